/* The checks and the vector reader shared by the C tests: firmware/tests/test_voxhap.c (make -C firmware test) and
 * local-ffi/tests/test_local_ffi.c (.ci/check-local-ffi.sh). One translation unit per test includes it once.
 *
 * CHECK(cond) and CHECK_EQ(a, b) count into `checks` and, when they fail, into `failures` and print the place (the
 * first 20 failures). load_vector(NAME) reads the `serial:` line of VECTORS_DIR/NAME.hex, VECTORS_DIR being
 * `vectors_dir` (a test sets it from its command line). */
#ifndef VOXHAP_TEST_CHECK_H
#define VOXHAP_TEST_CHECK_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

static int failures = 0, checks = 0;
static const char *vectors_dir = "../protocol/vectors";

#define CHECK_REPORT(...)                                                                                          \
    do {                                                                                                           \
        failures++;                                                                                                \
        if (failures <= 20) fprintf(stderr, __VA_ARGS__);                                                          \
    } while (0)
#define CHECK(cond)                                                                                                \
    do {                                                                                                           \
        checks++;                                                                                                  \
        if (!(cond)) CHECK_REPORT("%s:%d: check failed: %s\n", __FILE__, __LINE__, #cond);                        \
    } while (0)
#define CHECK_EQ(a, b)                                                                                             \
    do {                                                                                                           \
        unsigned long long va_ = (unsigned long long)(a), vb_ = (unsigned long long)(b);                           \
        checks++;                                                                                                  \
        if (va_ != vb_)                                                                                            \
            CHECK_REPORT("%s:%d: %s == %s failed: 0x%llx != 0x%llx\n", __FILE__, __LINE__, #a, #b, va_, vb_);      \
    } while (0)

/* The bytes of one wire frame (a vector's `serial:` line). */
typedef struct {
    uint8_t bytes[128];
    size_t len;
} wire;

/* Reads the `serial:` line of vectors_dir/NAME.hex; a missing file or line is a failure (an empty wire). */
static inline wire load_vector(const char *name) {
    char path[512], line[1024];
    wire w;
    FILE *f;
    int found = 0;
    memset(&w, 0, sizeof w);
    snprintf(path, sizeof path, "%s/%s.hex", vectors_dir, name);
    f = fopen(path, "r");
    if (!f) {
        CHECK_REPORT("cannot open %s\n", path);
        return w;
    }
    while (fgets(line, sizeof line, f)) {
        if (strncmp(line, "serial:", 7) == 0) {
            char *p = line + 7;
            unsigned v;
            int used;
            while (sscanf(p, " %2x%n", &v, &used) == 1 && w.len < sizeof w.bytes) {
                w.bytes[w.len++] = (uint8_t)v;
                p += used;
            }
            found = 1;
        }
    }
    fclose(f);
    if (!found) CHECK_REPORT("%s has no serial: line\n", path);
    return w;
}

#endif
