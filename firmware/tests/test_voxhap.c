/* Unit tests of the C firmware library. Every expected value comes from protocol/SPEC.md or the protocol/vectors files
 * (written by protocol/vectors/generate.py, an independent Python implementation), never from the code under test.
 * Run: make -C firmware test. Usage: test_voxhap VECTORS_DIR */
#include "voxhap.h"
#include "check.h"

#include <dirent.h>
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Decodes a whole host-to-device wire frame; returns the number of messages and the last one. */
static int decode_host(const wire *w, voxhap_host_msg *out) {
    voxhap_decoder d;
    size_t i;
    int n = 0;
    voxhap_decoder_init(&d);
    for (i = 0; i < w->len; i++) {
        if (voxhap_decoder_push_host(&d, w->bytes[i], out) == VOXHAP_OK) {
            n++;
        }
    }
    return n;
}

static int decode_device(const wire *w, voxhap_device_msg *out) {
    voxhap_decoder d;
    size_t i;
    int n = 0;
    voxhap_decoder_init(&d);
    for (i = 0; i < w->len; i++) {
        if (voxhap_decoder_push_device(&d, w->bytes[i], out) == VOXHAP_OK) {
            n++;
        }
    }
    return n;
}

static int same_bytes(const uint8_t *a, size_t alen, const wire *w) {
    return alen == w->len && memcmp(a, w->bytes, alen) == 0;
}

static void check_host_vector(const char *name, const voxhap_host_msg *expected, size_t wire_len) {
    wire w = load_vector(name);
    voxhap_host_msg got;
    uint8_t out[VOXHAP_MAX_WIRE_FRAME_LEN];
    size_t n;
    memset(&got, 0xAA, sizeof got);
    CHECK_EQ(w.len, wire_len); /* SPEC 4.2 "Sizes" */
    CHECK_EQ(decode_host(&w, &got), 1);
    CHECK_EQ(got.type, expected->type);
    switch (expected->type) {
    case VOXHAP_HELLO:
        CHECK_EQ(got.u.hello.major, expected->u.hello.major);
        CHECK_EQ(got.u.hello.minor, expected->u.hello.minor);
        break;
    case VOXHAP_ENABLE: CHECK_EQ(got.u.enable_watchdog_timeout_us, expected->u.enable_watchdog_timeout_us); break;
    case VOXHAP_SET_FORCE:
        CHECK_EQ(got.u.set_force.sequence, expected->u.set_force.sequence);
        CHECK(got.u.set_force.force_n[0] == expected->u.set_force.force_n[0]);
        CHECK(got.u.set_force.force_n[1] == expected->u.set_force.force_n[1]);
        CHECK(got.u.set_force.force_n[2] == expected->u.set_force.force_n[2]);
        CHECK_EQ(got.u.set_force.flags, expected->u.set_force.flags);
        break;
    case VOXHAP_HEARTBEAT: CHECK_EQ(got.u.heartbeat_counter, expected->u.heartbeat_counter); break;
    case VOXHAP_SET_STATE_RATE: CHECK_EQ(got.u.set_state_rate_hz, expected->u.set_state_rate_hz); break;
    default: break;
    }
    n = voxhap_encode_host(expected, out, sizeof out);
    CHECK(same_bytes(out, n, &w));
    if (!same_bytes(out, n, &w)) {
        fprintf(stderr, "  (encoding of %s differs from the vector)\n", name);
    }
}

static void check_device_vector(const char *name, const voxhap_device_msg *expected, size_t wire_len) {
    wire w = load_vector(name);
    voxhap_device_msg got;
    uint8_t out[VOXHAP_MAX_WIRE_FRAME_LEN];
    size_t n = voxhap_encode_device(expected, out, sizeof out);
    CHECK_EQ(w.len, wire_len);
    CHECK(same_bytes(out, n, &w));
    if (!same_bytes(out, n, &w)) {
        fprintf(stderr, "  (encoding of %s differs from the vector)\n", name);
    }
    memset(&got, 0xAA, sizeof got);
    CHECK_EQ(decode_device(&w, &got), 1);
    CHECK_EQ(got.type, expected->type);
    /* Every field of these messages is an integer, a float compared exactly, or a zero-padded label, and the
     * parser zeroes the struct first: a byte comparison of the union member is exact. */
    switch (expected->type) {
    case VOXHAP_DEVICE_INFO: {
        const voxhap_device_info *a = &got.u.device_info, *b = &expected->u.device_info;
        CHECK_EQ(a->version.major, b->version.major);
        CHECK_EQ(a->version.minor, b->version.minor);
        CHECK(memcmp(a->model, b->model, 12) == 0);
        CHECK(memcmp(a->serial_number, b->serial_number, 12) == 0);
        CHECK_EQ(a->position_dof, b->position_dof);
        CHECK_EQ(a->force_dof, b->force_dof);
        CHECK_EQ(a->button_count, b->button_count);
        CHECK_EQ(a->supported_rates, b->supported_rates);
        CHECK(memcmp(a->workspace_min_m, b->workspace_min_m, 12) == 0);
        CHECK(memcmp(a->workspace_max_m, b->workspace_max_m, 12) == 0);
        CHECK(a->max_force_n == b->max_force_n);
        CHECK(a->max_stiffness_n_per_m == b->max_stiffness_n_per_m);
        break;
    }
    case VOXHAP_STATE: {
        const voxhap_state *a = &got.u.state, *b = &expected->u.state;
        CHECK_EQ(a->sequence, b->sequence);
        CHECK_EQ(a->device_time_us, b->device_time_us);
        CHECK(memcmp(a->position_m, b->position_m, 12) == 0);
        CHECK(memcmp(a->velocity_m_per_s, b->velocity_m_per_s, 12) == 0);
        CHECK_EQ(a->last_force_sequence, b->last_force_sequence);
        CHECK_EQ(a->buttons, b->buttons);
        CHECK_EQ(a->status, b->status);
        CHECK_EQ(a->faults, b->faults);
        break;
    }
    case VOXHAP_HEARTBEAT_REPLY:
        CHECK_EQ(got.u.heartbeat_reply.counter, expected->u.heartbeat_reply.counter);
        CHECK_EQ(got.u.heartbeat_reply.device_time_us, expected->u.heartbeat_reply.device_time_us);
        CHECK_EQ(got.u.heartbeat_reply.status, expected->u.heartbeat_reply.status);
        break;
    case VOXHAP_FAULT:
        CHECK_EQ(got.u.fault.code, expected->u.fault.code);
        CHECK_EQ(got.u.fault.active_faults, expected->u.fault.active_faults);
        CHECK_EQ(got.u.fault.device_time_us, expected->u.fault.device_time_us);
        break;
    case VOXHAP_REJECTED:
        CHECK_EQ(got.u.rejected.message_type, expected->u.rejected.message_type);
        CHECK_EQ(got.u.rejected.reason, expected->u.rejected.reason);
        break;
    default: break;
    }
}

/* The device of device_info.hex: "v1.1, model voxhap-sim, serial SN0001, 3 position DOF, 3 force DOF, 2 buttons,
 * rates {250, 500, 1000} Hz, workspace (-0.08, -0.06, -0.05)..(0.08, 0.06, 0.05) m, 8.5 N, 2000 N/m". */
static voxhap_device_info vector_info(void) {
    voxhap_device_info i;
    memset(&i, 0, sizeof i);
    i.version.major = 1;
    i.version.minor = 1;
    memcpy(i.model, "voxhap-sim", 10);
    memcpy(i.serial_number, "SN0001", 6);
    i.position_dof = 3;
    i.force_dof = 3;
    i.button_count = 2;
    i.supported_rates = VOXHAP_RATE_250 | VOXHAP_RATE_500 | VOXHAP_RATE_1000;
    i.workspace_min_m[0] = -0.08f;
    i.workspace_min_m[1] = -0.06f;
    i.workspace_min_m[2] = -0.05f;
    i.workspace_max_m[0] = 0.08f;
    i.workspace_max_m[1] = 0.06f;
    i.workspace_max_m[2] = 0.05f;
    i.max_force_n = 8.5f;
    i.max_stiffness_n_per_m = 2000.0f;
    return i;
}

static const char *const known_vectors[] = {"hello", "hello_v1_0", "device_info_v1_0", "enable", "disable", "set_force", "heartbeat", "clear_fault",
                                            "set_state_rate", "device_info", "state", "heartbeat_reply",
                                            "fault_watchdog", "fault_over_current", "rejected"};

static void test_vectors(void) {
    voxhap_host_msg h;
    voxhap_device_msg d;
    DIR *dir;
    struct dirent *e;
    int seen = 0;

    /* Every .hex file is one this test checks (a new vector without a check fails here). */
    dir = opendir(vectors_dir);
    CHECK(dir != NULL);
    while (dir && (e = readdir(dir)) != NULL) {
        size_t len = strlen(e->d_name), k;
        int known = 0;
        if (len < 5 || strcmp(e->d_name + len - 4, ".hex") != 0) continue;
        for (k = 0; k < sizeof known_vectors / sizeof known_vectors[0]; k++) {
            if (strlen(known_vectors[k]) == len - 4 && strncmp(e->d_name, known_vectors[k], len - 4) == 0) {
                known = 1;
            }
        }
        if (!known) fprintf(stderr, "vector %s is not checked by the C tests\n", e->d_name);
        CHECK(known);
        seen++;
    }
    if (dir) closedir(dir);
    CHECK_EQ(seen, sizeof known_vectors / sizeof known_vectors[0]);

    memset(&h, 0, sizeof h);
    h.type = VOXHAP_HELLO;
    h.u.hello.major = 1;
    h.u.hello.minor = 1;
    check_host_vector("hello", &h, 7);
    h.u.hello.minor = 0; /* an older host's Hello stays valid (SPEC section 2) */
    check_host_vector("hello_v1_0", &h, 7);
    memset(&h, 0, sizeof h);
    h.type = VOXHAP_ENABLE;
    h.u.enable_watchdog_timeout_us = 50000;
    check_host_vector("enable", &h, 9);
    memset(&h, 0, sizeof h);
    h.type = VOXHAP_DISABLE;
    check_host_vector("disable", &h, 5);
    memset(&h, 0, sizeof h);
    h.type = VOXHAP_SET_FORCE;
    h.u.set_force.sequence = 7;
    h.u.set_force.force_n[0] = 0.5f;
    h.u.set_force.force_n[1] = -1.25f;
    h.u.set_force.force_n[2] = 2.0f;
    h.u.set_force.flags = VOXHAP_FORCE_REQUEST_STATE;
    check_host_vector("set_force", &h, 23);
    memset(&h, 0, sizeof h);
    h.type = VOXHAP_HEARTBEAT;
    h.u.heartbeat_counter = 42;
    check_host_vector("heartbeat", &h, 9);
    memset(&h, 0, sizeof h);
    h.type = VOXHAP_CLEAR_FAULT;
    check_host_vector("clear_fault", &h, 5);
    memset(&h, 0, sizeof h);
    h.type = VOXHAP_SET_STATE_RATE;
    h.u.set_state_rate_hz = 1000;
    check_host_vector("set_state_rate", &h, 7);

    memset(&d, 0, sizeof d);
    d.type = VOXHAP_DEVICE_INFO;
    d.u.device_info = vector_info();
    check_device_vector("device_info", &d, 67);
    d.u.device_info.version.minor = 0; /* an older device's DeviceInfo */
    check_device_vector("device_info_v1_0", &d, 67);
    memset(&d, 0, sizeof d);
    d.type = VOXHAP_STATE;
    d.u.state.sequence = 1000;
    d.u.state.device_time_us = 1234567890123ull;
    d.u.state.position_m[0] = 0.01f;
    d.u.state.position_m[1] = -0.02f;
    d.u.state.position_m[2] = 0.03f;
    d.u.state.velocity_m_per_s[0] = 0.1f;
    d.u.state.velocity_m_per_s[1] = 0.0f;
    d.u.state.velocity_m_per_s[2] = -0.25f;
    d.u.state.last_force_sequence = 999;
    d.u.state.buttons = 1;
    d.u.state.status = VOXHAP_STATUS_SESSION_OPEN | VOXHAP_STATUS_ENABLED;
    d.u.state.faults = 0;
    check_device_vector("state", &d, 51);
    memset(&d, 0, sizeof d);
    d.type = VOXHAP_HEARTBEAT_REPLY;
    d.u.heartbeat_reply.counter = 42;
    d.u.heartbeat_reply.device_time_us = 5000000;
    d.u.heartbeat_reply.status = VOXHAP_STATUS_SESSION_OPEN | VOXHAP_STATUS_LOCKSTEP;
    check_device_vector("heartbeat_reply", &d, 19);
    memset(&d, 0, sizeof d);
    d.type = VOXHAP_FAULT;
    d.u.fault.code = VOXHAP_FAULT_WATCHDOG_EXPIRED;
    d.u.fault.active_faults = 0;
    d.u.fault.device_time_us = 75000;
    check_device_vector("fault_watchdog", &d, 16);
    memset(&d, 0, sizeof d);
    d.type = VOXHAP_FAULT;
    d.u.fault.code = VOXHAP_FAULT_OVER_CURRENT;
    d.u.fault.active_faults = 0x000a;
    d.u.fault.device_time_us = 2000000;
    check_device_vector("fault_over_current", &d, 16);
    memset(&d, 0, sizeof d);
    d.type = VOXHAP_REJECTED;
    d.u.rejected.message_type = VOXHAP_ENABLE;
    d.u.rejected.reason = VOXHAP_REJECT_FAULTED;
    check_device_vector("rejected", &d, 7);
}

/* ------------------------------------------------------------------------------------------------ CRC, COBS */

static void test_crc(void) {
    const uint8_t check[] = "123456789";
    const uint8_t hello[] = {0x01, 0x01, 0x00};
    const uint8_t hello_1_1[] = {0x01, 0x01, 0x01};
    uint8_t b;
    CHECK_EQ(voxhap_crc16(check, 9), 0x29B1);   /* SPEC 4.2 check value */
    CHECK_EQ(voxhap_crc16(check, 0), 0xFFFF);   /* CRC of zero bytes */
    CHECK_EQ(voxhap_crc16(hello, 3), 0xC89D);   /* Hello(1.0) example */
    CHECK_EQ(voxhap_crc16(hello_1_1, 3), 0xD8BC); /* Hello(1.1) example */
    /* From a zero register one byte b gives T[b]: SPEC lists T[0], T[1], T[2], T[255]. */
    b = 0;
    CHECK_EQ(voxhap_crc16_update(0, &b, 1), 0x0000);
    b = 1;
    CHECK_EQ(voxhap_crc16_update(0, &b, 1), 0x1021);
    b = 2;
    CHECK_EQ(voxhap_crc16_update(0, &b, 1), 0x2042);
    b = 255;
    CHECK_EQ(voxhap_crc16_update(0, &b, 1), 0x1EF0);
    CHECK_EQ(voxhap_crc16_update(voxhap_crc16(check, 4), check + 4, 5), 0x29B1);
}

static void test_cobs(void) {
    /* SPEC 4.4 example: the unstuffed and wire bytes of set_force.hex. */
    const uint8_t raw[21] = {0x04, 0x07, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x3f, 0x00, 0x00,
                             0xa0, 0xbf, 0x00, 0x00, 0x00, 0x40, 0x01, 0x00, 0x37, 0xaf};
    const uint8_t stuffed[22] = {0x03, 0x04, 0x07, 0x01, 0x01, 0x01, 0x01, 0x01, 0x02, 0x3f, 0x01,
                                 0x03, 0xa0, 0xbf, 0x01, 0x01, 0x03, 0x40, 0x01, 0x03, 0x37, 0xaf};
    uint8_t out[300], back[300], big[254];
    size_t n, i;
    int m;
    n = voxhap_cobs_encode(raw, sizeof raw, out, sizeof out);
    CHECK_EQ(n, 22);
    CHECK(memcmp(out, stuffed, 22) == 0);
    m = voxhap_cobs_decode(stuffed, 22, back);
    CHECK_EQ(m, 21);
    CHECK(memcmp(back, raw, 21) == 0);
    CHECK_EQ(voxhap_cobs_encode(raw, sizeof raw, out, 21), 0); /* too small: refused */
    /* Cheshire & Baker: 254 non-zero bytes are code 0xFF + 254 bytes, then a final code 0x01. */
    for (i = 0; i < 254; i++) big[i] = (uint8_t)(i + 1);
    n = voxhap_cobs_encode(big, 254, out, sizeof out);
    CHECK_EQ(n, 256);
    CHECK_EQ(out[0], 0xFF);
    CHECK_EQ(out[255], 0x01);
    CHECK_EQ(voxhap_cobs_decode(out, n, back), 254);
    CHECK(memcmp(back, big, 254) == 0);
    /* Broken chains: a code promising more than is there; a zero byte inside. */
    {
        const uint8_t bad1[] = {0x05, 0x01};
        const uint8_t bad2[] = {0x02, 0x00, 0x01};
        CHECK_EQ(voxhap_cobs_decode(bad1, 2, back), -1);
        CHECK_EQ(voxhap_cobs_decode(bad2, 3, back), -1);
    }
}

/* A raw frame: type ‖ payload with a correct CRC (or a wrong one), stuffed and delimited, by hand. */
static size_t raw_frame(const uint8_t *body, size_t n, int corrupt_crc, uint8_t *out) {
    uint8_t buf[300];
    uint16_t crc;
    size_t s;
    memcpy(buf, body, n);
    crc = voxhap_crc16(body, n);
    if (corrupt_crc) crc ^= 1;
    buf[n] = (uint8_t)(crc & 0xFF);
    buf[n + 1] = (uint8_t)(crc >> 8);
    s = voxhap_cobs_encode(buf, n + 2, out, 300);
    out[s] = 0;
    return s + 1;
}

static int push_all(voxhap_decoder *d, const uint8_t *b, size_t n, int *last, voxhap_host_msg *m) {
    size_t i;
    int frames = 0;
    for (i = 0; i < n; i++) {
        int r = voxhap_decoder_push_host(d, b[i], m);
        if (r >= 0) {
            *last = r;
            frames++;
        }
    }
    return frames;
}

static void test_decoder_errors(void) {
    voxhap_decoder d;
    voxhap_host_msg m;
    uint8_t f[300];
    size_t n, i;
    int last = -1;
    wire hello = load_vector("hello");
    voxhap_decoder_init(&d);

    { /* LocalModel (type 0x08, protocol/vectors/local): this firmware announces 1.1 without the optional
       * local-model capability, so it drops the type as unknown (SPEC sections 2 and 10.1) */
        wire local = load_vector("local/local_model");
        voxhap_decoder fresh;
        voxhap_decoder_init(&fresh);
        CHECK_EQ(local.len, 67);
        CHECK_EQ(push_all(&fresh, local.bytes, local.len, &last, &m), 1);
        CHECK_EQ(last, VOXHAP_ERR_UNKNOWN_TYPE);
        CHECK_EQ(fresh.stats.unknown_type, 1);
    }
    { /* empty frames (idle filler) are ignored, not counted */
        const uint8_t zeros[] = {0, 0, 0};
        CHECK_EQ(push_all(&d, zeros, 3, &last, &m), 0);
    }
    { /* a delimiter while a code still promised data */
        const uint8_t b[] = {0x05, 0x01, 0x00};
        push_all(&d, b, 3, &last, &m);
        CHECK_EQ(last, VOXHAP_ERR_COBS);
        CHECK_EQ(d.stats.cobs_errors, 1);
    }
    { /* more than 65 unstuffed bytes: 70 non-zero bytes */
        for (i = 0; i < 70; i++) f[i] = 0x11;
        f[70] = 0;
        push_all(&d, f, 71, &last, &m);
        CHECK_EQ(last, VOXHAP_ERR_OVERSIZE);
        CHECK_EQ(d.stats.oversize, 1);
    }
    { /* fewer than 3 unstuffed bytes */
        const uint8_t b[] = {0x03, 0x01, 0x01, 0x00};
        push_all(&d, b, 4, &last, &m);
        CHECK_EQ(last, VOXHAP_ERR_TOO_SHORT);
        CHECK_EQ(d.stats.too_short, 1);
    }
    { /* CRC mismatch: the hello vector with one payload bit flipped */
        wire bad = hello;
        bad.bytes[2] ^= 0x02;
        push_all(&d, bad.bytes, bad.len, &last, &m);
        CHECK_EQ(last, VOXHAP_ERR_CRC);
        CHECK_EQ(d.stats.crc_errors, 1);
    }
    { /* unknown type for this direction: 0x08, and a device type 0x82 */
        const uint8_t b1[] = {0x08, 0x00};
        const uint8_t b2[] = {0x82, 0x00};
        n = raw_frame(b1, 2, 0, f);
        push_all(&d, f, n, &last, &m);
        CHECK_EQ(last, VOXHAP_ERR_UNKNOWN_TYPE);
        n = raw_frame(b2, 2, 0, f);
        push_all(&d, f, n, &last, &m);
        CHECK_EQ(last, VOXHAP_ERR_UNKNOWN_TYPE);
        CHECK_EQ(d.stats.unknown_type, 2);
    }
    { /* payload size differs: Hello with 3 bytes */
        const uint8_t b[] = {0x01, 0x01, 0x00, 0x00};
        n = raw_frame(b, 4, 0, f);
        push_all(&d, f, n, &last, &m);
        CHECK_EQ(last, VOXHAP_ERR_BAD_LENGTH);
        CHECK_EQ(d.stats.bad_length, 1);
    }
    { /* a NaN force and an infinite one (0x7fc00000, 0x7f800000 little-endian) */
        const uint8_t nan_b[] = {0x04, 1, 0, 0, 0, 0x00, 0x00, 0xc0, 0x7f, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0};
        const uint8_t inf_b[] = {0x04, 1, 0, 0, 0, 0, 0, 0, 0, 0x00, 0x00, 0x80, 0xff, 0, 0, 0, 0, 0, 0};
        n = raw_frame(nan_b, sizeof nan_b, 0, f);
        push_all(&d, f, n, &last, &m);
        CHECK_EQ(last, VOXHAP_ERR_INVALID_VALUE);
        n = raw_frame(inf_b, sizeof inf_b, 0, f);
        push_all(&d, f, n, &last, &m);
        CHECK_EQ(last, VOXHAP_ERR_INVALID_VALUE);
        CHECK_EQ(d.stats.invalid_value, 2);
    }
    CHECK_EQ(d.stats.frames_ok, 0);
    { /* resynchronisation: garbage without a delimiter, then 0x00, then a good frame decodes */
        const uint8_t garbage[] = {0x13, 0x11, 0xff, 0x42, 0x07};
        int frames;
        push_all(&d, garbage, sizeof garbage, &last, &m);
        f[0] = 0;
        push_all(&d, f, 1, &last, &m); /* the garbage is dropped here (counted somewhere) */
        frames = push_all(&d, hello.bytes, hello.len, &last, &m);
        CHECK_EQ(frames, 1);
        CHECK_EQ(last, VOXHAP_OK);
        CHECK_EQ(m.type, VOXHAP_HELLO);
        CHECK_EQ(d.stats.frames_ok, 1);
    }
    { /* oversize garbage much longer than the buffer, then a good frame */
        for (i = 0; i < 250; i++) f[i] = 0x55;
        f[250] = 0x00;
        CHECK_EQ(push_all(&d, f, 251, &last, &m), 1);
        CHECK_EQ(last, VOXHAP_ERR_OVERSIZE);
        CHECK_EQ(push_all(&d, hello.bytes, hello.len, &last, &m), 1);
        CHECK_EQ(last, VOXHAP_OK);
        /* without the delimiter, garbage and the frame after it are one (oversize) frame: SPEC 4.4 */
        CHECK_EQ(push_all(&d, f, 250, &last, &m), 0);
        CHECK_EQ(push_all(&d, hello.bytes, hello.len, &last, &m), 1);
        CHECK_EQ(last, VOXHAP_ERR_OVERSIZE);
    }
    { /* encoders refuse what must not be sent */
        voxhap_host_msg h;
        voxhap_device_msg dm;
        memset(&h, 0, sizeof h);
        h.type = VOXHAP_SET_FORCE;
        h.u.set_force.force_n[1] = NAN;
        CHECK_EQ(voxhap_encode_host(&h, f, 300), 0);
        memset(&dm, 0, sizeof dm);
        dm.type = VOXHAP_STATE;
        dm.u.state.velocity_m_per_s[2] = INFINITY;
        CHECK_EQ(voxhap_encode_device(&dm, f, 300), 0);
        memset(&dm, 0, sizeof dm);
        dm.type = VOXHAP_DEVICE_INFO;
        dm.u.device_info = vector_info();
        dm.u.device_info.model[3] = '\n'; /* not printable */
        CHECK_EQ(voxhap_encode_device(&dm, f, 300), 0);
        dm.u.device_info = vector_info();
        dm.u.device_info.model[11] = 'x'; /* text after the first zero */
        CHECK_EQ(voxhap_encode_device(&dm, f, 300), 0);
        dm.u.device_info = vector_info();
        dm.u.device_info.workspace_min_m[0] = 1.0f; /* min > max */
        CHECK_EQ(voxhap_encode_device(&dm, f, 300), 0);
        dm.u.device_info = vector_info();
        CHECK_EQ(voxhap_encode_device(&dm, f, 66), 0); /* 67 bytes do not fit in 66 */
        CHECK_EQ(voxhap_encode_device(&dm, f, 67), 67);
    }
}

/* ------------------------------------------------------------------------------------------------ session */

static voxhap_host_msg host(uint8_t type) {
    voxhap_host_msg m;
    memset(&m, 0, sizeof m);
    m.type = type;
    if (type == VOXHAP_HELLO) m.u.hello.major = 1;
    return m;
}

static voxhap_host_msg set_force(uint32_t seq, float x, float y, float z, uint16_t flags) {
    voxhap_host_msg m = host(VOXHAP_SET_FORCE);
    m.u.set_force.sequence = seq;
    m.u.set_force.force_n[0] = x;
    m.u.set_force.force_n[1] = y;
    m.u.set_force.force_n[2] = z;
    m.u.set_force.flags = flags;
    return m;
}

static voxhap_host_msg enable_msg(uint32_t timeout) {
    voxhap_host_msg m = host(VOXHAP_ENABLE);
    m.u.enable_watchdog_timeout_us = timeout;
    return m;
}

/* Drains the outbox into out (up to 16); returns the count. */
static int drain(voxhap_session *s, voxhap_device_msg *out) {
    int n = 0;
    voxhap_device_msg scratch;
    while (voxhap_session_poll_transmit(s, n < 16 ? &out[n] : &scratch)) n++;
    return n;
}

static void send_msg(voxhap_session *s, voxhap_host_msg m, uint64_t t) { voxhap_session_on_message(s, &m, t); }

static void test_session(void) {
    voxhap_session s;
    voxhap_device_info info = vector_info();
    voxhap_device_msg out[16];
    voxhap_sample sample;
    float f[3];
    uint64_t t = 1000;
    memset(&sample, 0, sizeof sample);
    sample.position_m[0] = 0.01f;
    info.max_force_n = 10.0f;
    CHECK_EQ(voxhap_session_init(&s, &info), VOXHAP_OK);
    CHECK_EQ(voxhap_session_status(&s) & VOXHAP_STATUS_SESSION_OPEN, 0);

    /* Session closed: SetForce ignored silently, others get Rejected(NO_SESSION), Heartbeat is always answered. */
    send_msg(&s, set_force(1, 1, 0, 0, 0), t);
    voxhap_session_poll(&s, t, &sample, f);
    CHECK_EQ(drain(&s, out), 0);
    send_msg(&s, enable_msg(0), t);
    send_msg(&s, host(VOXHAP_CLEAR_FAULT), t);
    {
        voxhap_host_msg hb = host(VOXHAP_HEARTBEAT);
        hb.u.heartbeat_counter = 99;
        send_msg(&s, hb, 1234);
    }
    CHECK_EQ(drain(&s, out), 3);
    CHECK_EQ(out[0].type, VOXHAP_REJECTED);
    CHECK_EQ(out[0].u.rejected.message_type, VOXHAP_ENABLE);
    CHECK_EQ(out[0].u.rejected.reason, VOXHAP_REJECT_NO_SESSION);
    CHECK_EQ(out[1].u.rejected.message_type, VOXHAP_CLEAR_FAULT);
    CHECK_EQ(out[2].type, VOXHAP_HEARTBEAT_REPLY);
    CHECK_EQ(out[2].u.heartbeat_reply.counter, 99);
    CHECK_EQ(out[2].u.heartbeat_reply.device_time_us, 1234);
    CHECK_EQ(out[2].u.heartbeat_reply.status & VOXHAP_STATUS_SESSION_OPEN, 0);

    /* Hello with another major: DeviceInfo, then Rejected(VERSION_MISMATCH); session stays closed. */
    {
        voxhap_host_msg h = host(VOXHAP_HELLO);
        h.u.hello.major = 2;
        send_msg(&s, h, t);
    }
    CHECK_EQ(drain(&s, out), 2);
    CHECK_EQ(out[0].type, VOXHAP_DEVICE_INFO);
    CHECK(memcmp(out[0].u.device_info.model, "voxhap-sim", 10) == 0);
    CHECK_EQ(out[1].type, VOXHAP_REJECTED);
    CHECK_EQ(out[1].u.rejected.message_type, VOXHAP_HELLO);
    CHECK_EQ(out[1].u.rejected.reason, VOXHAP_REJECT_VERSION_MISMATCH);
    CHECK_EQ(voxhap_session_status(&s) & VOXHAP_STATUS_SESSION_OPEN, 0);

    /* Hello 1.x (any minor): DeviceInfo only, session open, lockstep. */
    {
        voxhap_host_msg h = host(VOXHAP_HELLO);
        h.u.hello.minor = 7;
        send_msg(&s, h, t);
    }
    CHECK_EQ(drain(&s, out), 1);
    CHECK_EQ(out[0].type, VOXHAP_DEVICE_INFO);
    CHECK_EQ(voxhap_session_status(&s), VOXHAP_STATUS_SESSION_OPEN | VOXHAP_STATUS_LOCKSTEP);

    /* Idle: SetForce recorded and answered by one State in lockstep, but not applied. REQUEST_STATE changes
     * nothing in lockstep. */
    send_msg(&s, set_force(5, 3, 0, 0, VOXHAP_FORCE_REQUEST_STATE), t);
    voxhap_session_poll(&s, t, &sample, f);
    CHECK(f[0] == 0.0f && f[1] == 0.0f && f[2] == 0.0f);
    CHECK_EQ(drain(&s, out), 1);
    CHECK_EQ(out[0].type, VOXHAP_STATE);
    CHECK_EQ(out[0].u.state.last_force_sequence, 5);
    CHECK_EQ(out[0].u.state.device_time_us, t);
    CHECK(out[0].u.state.position_m[0] == 0.01f);
    voxhap_session_poll(&s, t + 1, &sample, f); /* no SetForce since: no State */
    CHECK_EQ(drain(&s, out), 0);

    /* Enable: bad timeouts refused (SPEC: 0 = default, else 1 000 ..= 1 000 000 us). */
    send_msg(&s, enable_msg(999), t);
    send_msg(&s, enable_msg(1000001), t);
    CHECK_EQ(drain(&s, out), 2);
    CHECK_EQ(out[0].u.rejected.reason, VOXHAP_REJECT_INVALID_ARGUMENT);
    CHECK_EQ(out[1].u.rejected.message_type, VOXHAP_ENABLE);
    CHECK_EQ(voxhap_session_status(&s) & VOXHAP_STATUS_ENABLED, 0);
    send_msg(&s, enable_msg(0), t);
    CHECK_EQ(drain(&s, out), 0); /* success is not answered */
    CHECK_EQ(voxhap_session_status(&s) & VOXHAP_STATUS_ENABLED, VOXHAP_STATUS_ENABLED);
    CHECK_EQ(s.watchdog_timeout_us, 50000);

    /* Enabled: force applied; a longer one scaled to 10 N keeping direction: (30, 40, 0) -> (6, 8, 0). */
    send_msg(&s, set_force(6, 1.5f, -2.0f, 0.25f, 0), t);
    voxhap_session_poll(&s, t, &sample, f);
    CHECK(f[0] == 1.5f && f[1] == -2.0f && f[2] == 0.25f);
    CHECK_EQ(drain(&s, out), 1);
    CHECK_EQ(out[0].u.state.status & VOXHAP_STATUS_FORCE_CLAMPED, 0);
    send_msg(&s, set_force(7, 30, 40, 0, 0), t);
    voxhap_session_poll(&s, t, &sample, f);
    CHECK(fabs(f[0] - 6.0) < 1e-5 && fabs(f[1] - 8.0) < 1e-5 && f[2] == 0.0f);
    CHECK_EQ(drain(&s, out), 1);
    CHECK_EQ(out[0].u.state.status & VOXHAP_STATUS_FORCE_CLAMPED, VOXHAP_STATUS_FORCE_CLAMPED);
    send_msg(&s, set_force(8, 1, 0, 0, 0), t);
    voxhap_session_poll(&s, t, &sample, f);
    CHECK_EQ(drain(&s, out), 1);
    CHECK_EQ(out[0].u.state.status & VOXHAP_STATUS_FORCE_CLAMPED, 0);

    /* Watchdog: a Heartbeat does not feed it; at exactly the timeout it holds, one microsecond later it fires. */
    {
        voxhap_host_msg hb = host(VOXHAP_HEARTBEAT);
        send_msg(&s, hb, t + 40000);
    }
    voxhap_session_poll(&s, t + 50000, &sample, f);
    CHECK(f[0] == 1.0f);
    CHECK_EQ(drain(&s, out), 1); /* the heartbeat reply */
    voxhap_session_poll(&s, t + 50001, &sample, f);
    CHECK(f[0] == 0.0f && f[1] == 0.0f && f[2] == 0.0f);
    CHECK_EQ(drain(&s, out), 1);
    CHECK_EQ(out[0].type, VOXHAP_FAULT);
    CHECK_EQ(out[0].u.fault.code, VOXHAP_FAULT_WATCHDOG_EXPIRED);
    CHECK_EQ(out[0].u.fault.active_faults, 0);
    CHECK_EQ(out[0].u.fault.device_time_us, t + 50001);
    CHECK_EQ(voxhap_session_status(&s), VOXHAP_STATUS_SESSION_OPEN | VOXHAP_STATUS_LOCKSTEP |
                                            VOXHAP_STATUS_WATCHDOG_TRIPPED);
    CHECK_EQ(s.stats.watchdog_trips, 1);
    /* No self re-enable: a later SetForce is not applied. */
    send_msg(&s, set_force(9, 2, 0, 0, 0), t + 60000);
    voxhap_session_poll(&s, t + 60000, &sample, f);
    CHECK(f[0] == 0.0f);
    CHECK_EQ(drain(&s, out), 1);
    CHECK_EQ(out[0].u.state.last_force_sequence, 9);
    CHECK_EQ(out[0].u.state.status & VOXHAP_STATUS_WATCHDOG_TRIPPED, VOXHAP_STATUS_WATCHDOG_TRIPPED);
    /* Hello does not clear WATCHDOG_TRIPPED; the next accepted Enable does. An Enable holds zero until SetForce. */
    send_msg(&s, host(VOXHAP_HELLO), t + 60000);
    CHECK_EQ(voxhap_session_status(&s) & VOXHAP_STATUS_WATCHDOG_TRIPPED, VOXHAP_STATUS_WATCHDOG_TRIPPED);
    send_msg(&s, enable_msg(1000), t + 60000);
    CHECK_EQ(voxhap_session_status(&s) & VOXHAP_STATUS_WATCHDOG_TRIPPED, 0);
    voxhap_session_poll(&s, t + 60000, &sample, f);
    CHECK(f[0] == 0.0f);
    send_msg(&s, set_force(10, 2, 0, 0, 0), t + 60500);
    voxhap_session_poll(&s, t + 61500, &sample, f);
    CHECK(f[0] == 2.0f);
    voxhap_session_poll(&s, t + 61501, &sample, f); /* 1 ms timeout set by this Enable */
    CHECK(f[0] == 0.0f);
    drain(&s, out);

    /* Hello while Enabled: back to Idle, zero force, default watchdog (SPEC 6: "a Hello always starts over"). */
    send_msg(&s, enable_msg(2000), t + 65000);
    send_msg(&s, set_force(1, 2, 0, 0, 0), t + 65000);
    send_msg(&s, host(VOXHAP_HELLO), t + 65001);
    voxhap_session_poll(&s, t + 65001, &sample, f);
    CHECK(f[0] == 0.0f);
    CHECK_EQ(voxhap_session_status(&s) & VOXHAP_STATUS_ENABLED, 0);
    CHECK_EQ(s.watchdog_timeout_us, 50000);
    drain(&s, out);

    /* Disable: zero force, Idle. */
    send_msg(&s, enable_msg(0), t + 70000);
    send_msg(&s, set_force(11, 2, 0, 0, 0), t + 70000);
    send_msg(&s, host(VOXHAP_DISABLE), t + 70000);
    voxhap_session_poll(&s, t + 70000, &sample, f);
    CHECK(f[0] == 0.0f);
    CHECK_EQ(voxhap_session_status(&s) & VOXHAP_STATUS_ENABLED, 0);
    drain(&s, out);

    /* Latching fault: Faulted, Fault(code, active), Enable refused, Hello and Disable do not clear, ClearFault does. */
    send_msg(&s, enable_msg(0), t + 80000);
    voxhap_session_raise_fault(&s, VOXHAP_FAULT_EMERGENCY_STOP, t + 80001);
    voxhap_session_raise_fault(&s, VOXHAP_FAULT_OVER_CURRENT, t + 80002);
    CHECK_EQ(drain(&s, out), 2);
    CHECK_EQ(out[0].u.fault.code, 1);
    CHECK_EQ(out[0].u.fault.active_faults, 0x0002);
    CHECK_EQ(out[1].u.fault.code, 3);
    CHECK_EQ(out[1].u.fault.active_faults, 0x000a); /* as in fault_over_current.hex */
    send_msg(&s, enable_msg(0), t + 80003);
    CHECK_EQ(drain(&s, out), 1);
    CHECK_EQ(out[0].u.rejected.message_type, VOXHAP_ENABLE);
    CHECK_EQ(out[0].u.rejected.reason, VOXHAP_REJECT_FAULTED);
    send_msg(&s, host(VOXHAP_HELLO), t + 80004);
    send_msg(&s, host(VOXHAP_DISABLE), t + 80004);
    CHECK_EQ(voxhap_session_status(&s) & VOXHAP_STATUS_FAULTED, VOXHAP_STATUS_FAULTED);
    send_msg(&s, set_force(1, 3, 0, 0, 0), t + 80005);
    voxhap_session_poll(&s, t + 80005, &sample, f);
    CHECK(f[0] == 0.0f);
    drain(&s, out);
    CHECK_EQ(out[1].type, VOXHAP_STATE);
    CHECK_EQ(out[1].u.state.faults, 0x000a);
    send_msg(&s, host(VOXHAP_CLEAR_FAULT), t + 80006);
    CHECK_EQ(voxhap_session_status(&s) & (VOXHAP_STATUS_FAULTED | VOXHAP_STATUS_ENABLED), 0);
    CHECK_EQ(s.faults, 0);
    voxhap_session_raise_fault(&s, 200, t); /* codes above 15 are reported as INTERNAL (7) */
    CHECK_EQ(drain(&s, out), 1);
    CHECK_EQ(out[0].u.fault.code, VOXHAP_FAULT_INTERNAL);
    send_msg(&s, host(VOXHAP_CLEAR_FAULT), t);

    /* Non-finite sample: ENCODER once, no State while non-finite; one State at the first finite sample. */
    {
        voxhap_sample bad = sample;
        bad.velocity_m_per_s[1] = NAN;
        send_msg(&s, set_force(20, 0, 0, 0, 0), t + 90000);
        voxhap_session_poll(&s, t + 90000, &bad, f);
        send_msg(&s, set_force(21, 0, 0, 0, 0), t + 90001);
        voxhap_session_poll(&s, t + 90001, &bad, f);
        CHECK_EQ(drain(&s, out), 1);
        CHECK_EQ(out[0].type, VOXHAP_FAULT);
        CHECK_EQ(out[0].u.fault.code, VOXHAP_FAULT_ENCODER);
        voxhap_session_poll(&s, t + 90002, &sample, f);
        CHECK_EQ(drain(&s, out), 1);
        CHECK_EQ(out[0].type, VOXHAP_STATE);
        CHECK_EQ(out[0].u.state.last_force_sequence, 21);
        send_msg(&s, host(VOXHAP_CLEAR_FAULT), t);
    }

    /* Streaming: SetStateRate(1000) supported, 300 refused; a State every 1 ms without SetForce; no burst after a
     * gap; REQUEST_STATE adds one State. */
    {
        voxhap_host_msg r = host(VOXHAP_SET_STATE_RATE);
        uint64_t t0 = 2000000;
        int k, states = 0;
        r.u.set_state_rate_hz = 300;
        send_msg(&s, r, t0);
        CHECK_EQ(drain(&s, out), 1);
        CHECK_EQ(out[0].u.rejected.message_type, VOXHAP_SET_STATE_RATE);
        CHECK_EQ(out[0].u.rejected.reason, VOXHAP_REJECT_INVALID_ARGUMENT);
        r.u.set_state_rate_hz = 1000;
        send_msg(&s, r, t0);
        CHECK_EQ(drain(&s, out), 0);
        CHECK_EQ(voxhap_session_status(&s) & VOXHAP_STATUS_LOCKSTEP, 0);
        for (k = 0; k < 10; k++) { /* polls every 0.5 ms for 5 ms: 5 States */
            voxhap_session_poll(&s, t0 + (uint64_t)k * 500u, &sample, f);
            states += drain(&s, out);
        }
        CHECK_EQ(states, 5);
        voxhap_session_poll(&s, t0 + 20000, &sample, f); /* 15 ms late: one State, not 15 */
        CHECK_EQ(drain(&s, out), 1);
        send_msg(&s, set_force(30, 0, 0, 0, 0), t0 + 20100);
        voxhap_session_poll(&s, t0 + 20100, &sample, f);
        CHECK_EQ(drain(&s, out), 0); /* streaming: SetForce alone asks for nothing */
        send_msg(&s, set_force(31, 0, 0, 0, VOXHAP_FORCE_REQUEST_STATE), t0 + 20200);
        voxhap_session_poll(&s, t0 + 20200, &sample, f);
        CHECK_EQ(drain(&s, out), 1);
        CHECK_EQ(out[0].u.state.last_force_sequence, 31);
        send_msg(&s, host(VOXHAP_HELLO), t0); /* back to lockstep */
        CHECK_EQ(voxhap_session_status(&s) & VOXHAP_STATUS_LOCKSTEP, VOXHAP_STATUS_LOCKSTEP);
        drain(&s, out);
    }

    /* Outbox: 8 messages; the 9th (newest) is dropped and counted. */
    {
        int k;
        for (k = 0; k < 9; k++) {
            voxhap_host_msg hb = host(VOXHAP_HEARTBEAT);
            hb.u.heartbeat_counter = (uint32_t)k;
            send_msg(&s, hb, t);
        }
        CHECK_EQ(drain(&s, out), 8);
        CHECK_EQ(out[0].u.heartbeat_reply.counter, 0);
        CHECK_EQ(out[7].u.heartbeat_reply.counter, 7);
        CHECK_EQ(s.stats.outbox_overflows, 1);
    }

    /* An info that could not be sent is refused at init. */
    info.max_force_n = NAN;
    CHECK_EQ(voxhap_session_init(&s, &info), VOXHAP_ERR_INVALID_VALUE);
}

/* ------------------------------------------------------------------------------------------------ clamp, slew */

static double norm_d(const float v[3]) {
    return sqrt((double)v[0] * v[0] + (double)v[1] * v[1] + (double)v[2] * v[2]);
}

static void test_clamp(void) {
    /* SPEC 6.2: |applied| <= max * (1 + 1e-6), direction kept; measured here in double, independently. */
    uint32_t seed = 12345;
    int k;
    float out[3];
    const float huge[3] = {FLT_MAX, -FLT_MAX, FLT_MAX};
    const float tiny[3] = {1e-38f, 0.0f, -1e-45f};
    CHECK_EQ(voxhap_clamp_magnitude(huge, 8.5f, out), 1);
    CHECK(norm_d(out) <= 8.5 * (1 + 1e-6));
    CHECK(fabs(out[0] - 8.5 / sqrt(3.0)) < 1e-5 && out[1] < 0.0f && out[2] > 0.0f);
    CHECK_EQ(voxhap_clamp_magnitude(tiny, 8.5f, out), 0);
    CHECK(out[0] == tiny[0] && out[2] == tiny[2]);
    {
        const float f[3] = {1.0f, 0.0f, 0.0f};
        CHECK_EQ(voxhap_clamp_magnitude(f, 0.0f, out), 1); /* a device whose max is 0 applies nothing */
        CHECK(out[0] == 0.0f);
    }
    for (k = 0; k < 200000; k++) {
        float f[3], max_n;
        double n_in, n_out, dot;
        int i, clamped;
        for (i = 0; i < 3; i++) {
            /* a random sign, mantissa and exponent: magnitudes 1e-30 .. 1e30 */
            seed = seed * 1664525u + 1013904223u;
            f[i] = (float)(((seed >> 8) & 0xFFFF) / 65536.0 * pow(10.0, (int)((seed >> 24) % 61) - 30));
            if (seed & 1) f[i] = -f[i];
        }
        seed = seed * 1664525u + 1013904223u;
        max_n = (float)((seed >> 8) % 10000) / 100.0f;
        clamped = voxhap_clamp_magnitude(f, max_n, out);
        n_in = norm_d(f);
        n_out = norm_d(out);
        CHECK(n_out <= max_n * (1 + 1e-6) + 1e-37);
        if (n_in <= max_n * (1 - 1e-6)) {
            CHECK(!clamped && out[0] == f[0] && out[1] == f[1] && out[2] == f[2]);
        }
        if (clamped && max_n > 0 && n_in > 0) {
            dot = ((double)f[0] * out[0] + (double)f[1] * out[1] + (double)f[2] * out[2]) / (n_in * n_out);
            CHECK(dot > 1 - 1e-6); /* same direction */
            CHECK(n_out >= max_n * (1 - 1e-6));
        }
        if (failures > 20) break;
    }
}

static void test_slew(void) {
    const float zero[3] = {0, 0, 0}, f[3] = {3, 4, 0}, half[3] = {1.5f, 2, 0};
    float out[3];
    voxhap_slew_limit(zero, f, 1.0f, out); /* |f| = 5 from 0, rise 1: (0.6, 0.8, 0) */
    CHECK(fabs(out[0] - 0.6) < 1e-6 && fabs(out[1] - 0.8) < 1e-6 && out[2] == 0.0f);
    voxhap_slew_limit(half, f, 10.0f, out); /* within the rise: unchanged */
    CHECK(out[0] == 3.0f && out[1] == 4.0f);
    voxhap_slew_limit(f, zero, 0.001f, out); /* falls are never limited */
    CHECK(out[0] == 0.0f && out[1] == 0.0f);
    voxhap_slew_limit(f, half, 0.0f, out);
    CHECK(out[0] == 1.5f && out[1] == 2.0f);
}

/* ------------------------------------------------------------------------------------------------ firmware + HAL */

typedef struct {
    uint64_t now;
    const uint8_t *rx;
    size_t rx_len, rx_pos;
    uint8_t tx[4096];
    size_t tx_len;
    float force[3];
    int force_writes;
    uint16_t hw_faults;
    int messages_seen;
} fake_board;

static uint64_t fb_now(void *c) { return ((fake_board *)c)->now; }
static size_t fb_read(void *c, uint8_t *buf, size_t cap) {
    fake_board *b = c;
    size_t n = b->rx_len - b->rx_pos;
    if (n > cap) n = cap;
    memcpy(buf, b->rx + b->rx_pos, n);
    b->rx_pos += n;
    return n;
}
static void fb_write(void *c, const uint8_t *buf, size_t len) {
    fake_board *b = c;
    if (b->tx_len + len <= sizeof b->tx) {
        memcpy(b->tx + b->tx_len, buf, len);
        b->tx_len += len;
    }
}
static void fb_sample(void *c, voxhap_sample *s) {
    (void)c;
    s->position_m[0] = 0.01f;
}
static void fb_force(void *c, const float f[3]) {
    fake_board *b = c;
    memcpy(b->force, f, sizeof b->force);
    b->force_writes++;
}
static uint16_t fb_faults(void *c) { return ((fake_board *)c)->hw_faults; }
static void fb_msg(void *c, const voxhap_host_msg *m, uint64_t now) {
    (void)m;
    (void)now;
    ((fake_board *)c)->messages_seen++;
}

static void feed(voxhap_fw *fw, fake_board *b, const uint8_t *bytes, size_t n) {
    b->rx = bytes;
    b->rx_len = n;
    b->rx_pos = 0;
    voxhap_fw_tick(fw);
}

static void test_firmware(void) {
    static fake_board b;
    static voxhap_fw fw;
    voxhap_hal hal;
    voxhap_device_info info = vector_info();
    wire hello = load_vector("hello"), hb = load_vector("heartbeat"), di = load_vector("device_info");
    wire reply = load_vector("heartbeat_reply"), en = load_vector("enable"), sf = load_vector("set_force");
    wire fault = load_vector("fault_over_current");
    memset(&b, 0, sizeof b);
    hal.ctx = &b;
    hal.now_us = fb_now;
    hal.uart_read = fb_read;
    hal.uart_write = fb_write;
    hal.read_sample = fb_sample;
    hal.write_force = fb_force;
    hal.read_faults = fb_faults;
    hal.on_message = fb_msg;
    hal.on_reply = NULL;
    CHECK_EQ(voxhap_fw_init(&fw, &hal, &info, 1000.0f), VOXHAP_OK); /* rise at most 1 N per ms */
    voxhap_fw_start(&fw);
    /* SPEC 4.3: a lone 0x00 first, before any other byte; zero force written. */
    CHECK_EQ(b.tx_len, 1);
    CHECK_EQ(b.tx[0], 0x00);
    CHECK_EQ(b.force_writes, 1);

    /* Hello → 0x00 then exactly the DeviceInfo vector (this board is the vector's device). */
    b.tx_len = 0;
    feed(&fw, &b, hello.bytes, hello.len);
    CHECK_EQ(b.tx_len, 1 + di.len);
    CHECK_EQ(b.tx[0], 0x00);
    CHECK(b.tx_len == 1 + di.len && memcmp(b.tx + 1, di.bytes, di.len) == 0);

    /* Heartbeat(42) at 5 000 000 us → exactly the heartbeat_reply vector (SESSION_OPEN|LOCKSTEP). */
    b.tx_len = 0;
    b.now = 5000000;
    feed(&fw, &b, hb.bytes, hb.len);
    CHECK(same_bytes(b.tx, b.tx_len, &reply));

    /* Enable, then SetForce (0.5, -1.25, 2.0) (|f| = 2.40 N): the slew limit lets |f| rise 1 N per ms. */
    feed(&fw, &b, en.bytes, en.len);
    b.now += 1000;
    b.tx_len = 0;
    feed(&fw, &b, sf.bytes, sf.len);
    CHECK(fabs(norm_d(b.force) - 1.0) < 1e-5);
    CHECK(fabs(b.force[1] / b.force[0] + 2.5) < 1e-5); /* direction of (0.5, -1.25, 2.0) */
    b.now += 1000;
    feed(&fw, &b, sf.bytes, sf.len);
    CHECK(fabs(norm_d(b.force) - 2.0) < 1e-5);
    b.now += 1000;
    feed(&fw, &b, sf.bytes, sf.len);
    CHECK(b.force[0] == 0.5f && b.force[1] == -1.25f && b.force[2] == 2.0f);
    CHECK_EQ(b.messages_seen, 6);

    /* Hardware faults 1 and 3 present: Fault(1), Fault(3) once each (the second is fault_over_current.hex at its
     * time), zero force at once; they are not raised again while latched. */
    /* (A fresh board: device time starts again at 0 and must not go backwards.) */
    memset(&b, 0, sizeof b);
    CHECK_EQ(voxhap_fw_init(&fw, &hal, &info, 1000.0f), VOXHAP_OK);
    voxhap_fw_start(&fw);
    feed(&fw, &b, hello.bytes, hello.len);
    feed(&fw, &b, en.bytes, en.len);
    b.now = 1000;
    feed(&fw, &b, sf.bytes, sf.len);
    CHECK(norm_d(b.force) > 0.5);
    b.hw_faults = (1u << 1);
    b.now = 1999000;
    voxhap_fw_control(&fw);
    CHECK(b.force[0] == 0.0f && b.force[1] == 0.0f && b.force[2] == 0.0f);
    b.hw_faults = (1u << 1) | (1u << 3);
    b.now = 2000000;
    b.tx_len = 0;
    voxhap_fw_control(&fw);
    CHECK(same_bytes(b.tx, b.tx_len, &fault));
    b.tx_len = 0;
    voxhap_fw_control(&fw);
    CHECK_EQ(b.tx_len, 0);
}

int main(int argc, char **argv) {
    if (argc > 1) vectors_dir = argv[1];
    test_crc();
    test_cobs();
    test_vectors();
    test_decoder_errors();
    test_session();
    test_clamp();
    test_slew();
    test_firmware();
    if (failures) {
        fprintf(stderr, "FAILED: %d of %d checks\n", failures, checks);
        return 1;
    }
    printf("firmware unit tests: %d checks passed\n", checks);
    return 0;
}
