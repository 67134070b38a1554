/* The C interface to voxhap-local (include/voxhap_local.h) driven as a C firmware would drive it, with the
 * host's messages taken from protocol/vectors (written by protocol/vectors/generate.py, an implementation of
 * SPEC.md independent of the Rust code). Expected forces come from SPEC section 10.5 and the vector's model, by
 * hand: local/local_model_wall.hex is a floor at z = 0 (plane, normal +z, 20 N), stiffness 2000 N/m, no damping,
 * force limit 3 N. A still handle d below the floor (k d <= 20 N) holds the proxy on the surface, so the force is
 * k d up: 1.0 N at d = 0.5 mm; at d = 2 mm, 4 N clamped to the 3 N limit. Tolerance (SPEC 10.5): k (bound +
 * 1 um) with the loop's 0.1 um solver tolerance, 2000 * 1.1e-6 = 0.0022 N; the clamp within 1e-6 relative.
 *
 * Usage: test_local_ffi VECTORS_DIR. Exit status 0 when every check passes. */
#include "voxhap_local.h"
#include "check.h" /* firmware/tests/check.h */

#include <math.h>
#include <stdio.h>
#include <string.h>

static uint64_t storage[VOXHAP_LOCAL_STORAGE_WORDS];
static uint64_t now_us = 0;
static float force[3];
static unsigned frames_sent = 0;
static uint64_t last_model_us = 0;

static float magnitude(const float f[3]) { return sqrtf(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]); }

/* One 100 us control cycle with the handle still at height z (m); drains the transmit queue. */
static void cycle(float z) {
    const float position[3] = {0.0f, 0.0f, z}, velocity[3] = {0.0f, 0.0f, 0.0f};
    uint8_t out[VOXHAP_LOCAL_MAX_FRAME];
    int32_t n;
    now_us += 100;
    CHECK(voxhap_local_step(storage, sizeof storage, now_us, position, velocity, 0, force) == VOXHAP_LOCAL_OK);
    while ((n = voxhap_local_transmit(storage, sizeof storage, out, sizeof out)) > 0) {
        CHECK(out[n - 1] == 0); /* every frame ends with its delimiter */
        frames_sent++;
    }
    CHECK(n == 0);
}

static void receive(const wire *w) {
    CHECK(voxhap_local_receive(storage, sizeof storage, w->bytes, w->len, now_us) == 1);
    last_model_us = now_us;
}

int main(int argc, char **argv) {
    voxhap_local_info info;
    wire hello, enable, model;
    int i, status;
    float previous = 0.0f, largest_rise = 0.0f;
    if (argc > 1) vectors_dir = argv[1];
    hello = load_vector("hello");
    enable = load_vector("enable");
    model = load_vector("local/local_model_wall");

    /* The storage the header promises is enough, and the library agrees with the header. */
    CHECK(voxhap_local_storage_size() <= sizeof storage);
    CHECK(voxhap_local_storage_align() <= sizeof(uint64_t));
    CHECK(voxhap_local_max_frame() == VOXHAP_LOCAL_MAX_FRAME);

    memset(&info, 0, sizeof info);
    memcpy(info.model, "c-arm", 5);
    memcpy(info.serial_number, "1", 1);
    info.position_dof = 3;
    info.force_dof = 3;
    info.supported_rates = 0x18; /* 500 and 1000 Hz */
    for (i = 0; i < 3; i++) {
        info.workspace_min_m[i] = -0.1f;
        info.workspace_max_m[i] = 0.1f;
    }
    info.max_force_n = 5.0f;
    info.max_stiffness_n_per_m = 2000.0f;

    /* Bad input is refused, and nothing is initialised by it. */
    CHECK(voxhap_local_init(NULL, sizeof storage, &info, 100) == VOXHAP_LOCAL_ENULL);
    CHECK(voxhap_local_init(storage, 16, &info, 100) == VOXHAP_LOCAL_ESTORAGE);
    CHECK(voxhap_local_init((uint8_t *)storage + 1, sizeof storage - 1, &info, 100) == VOXHAP_LOCAL_ESTORAGE);
    CHECK(voxhap_local_status(storage, sizeof storage) == VOXHAP_LOCAL_EINIT);
    info.max_force_n = NAN;
    CHECK(voxhap_local_init(storage, sizeof storage, &info, 100) == VOXHAP_LOCAL_EINFO);
    info.max_force_n = 5.0f;
    info.model[0] = 0x07; /* not printable */
    CHECK(voxhap_local_init(storage, sizeof storage, &info, 100) == VOXHAP_LOCAL_EINFO);
    info.model[0] = 'c';

    CHECK(voxhap_local_init(storage, sizeof storage, &info, 100) == VOXHAP_LOCAL_OK);
    /* SPEC 10.1: the capability bit in every status word, from power-up. */
    status = voxhap_local_status(storage, sizeof storage);
    CHECK(status >= 0 && (status & VOXHAP_LOCAL_STATUS_LOCAL_MODEL) != 0);

    /* Hello (1.1) opens the session (DeviceInfo goes out); Enable (watchdog 50 ms) arms the drive. */
    receive(&hello);
    cycle(0.001f);
    CHECK(frames_sent >= 1);
    status = voxhap_local_status(storage, sizeof storage);
    CHECK((status & 0x0001) != 0); /* SESSION_OPEN */
    receive(&enable);
    cycle(0.001f);
    CHECK((voxhap_local_status(storage, sizeof storage) & 0x0002) != 0); /* ENABLED */

    /* 0.6 s above the floor with a model every 1 ms: no contact, zero force, and the engage ramp (0.5 s) runs. */
    for (i = 0; i < 6000; i++) {
        if (i % 10 == 0) receive(&model);
        cycle(0.001f);
        CHECK(magnitude(force) == 0.0f);
    }
    /* 0.1 s 0.5 mm below it: 1.0 N up, reached through the 0.5 N/ms slew limit (0.05 N a 100 us cycle). */
    for (i = 0; i < 1000; i++) {
        if (i % 10 == 0) receive(&model);
        cycle(-0.0005f);
        if (magnitude(force) - previous > largest_rise) largest_rise = magnitude(force) - previous;
        previous = magnitude(force);
    }
    CHECK(fabsf(force[0]) <= 0.0022f && fabsf(force[1]) <= 0.0022f);
    CHECK(fabsf(force[2] - 1.0f) <= 0.0022f);
    /* 0.1 s 2 mm below: k d = 4 N, clamped to the model's 3 N limit. */
    for (i = 0; i < 1000; i++) {
        if (i % 10 == 0) receive(&model);
        cycle(-0.002f);
        CHECK(magnitude(force) <= 3.0f * (1.0f + 1e-6f));
        if (magnitude(force) - previous > largest_rise) largest_rise = magnitude(force) - previous;
        previous = magnitude(force);
    }
    CHECK(fabsf(force[2] - 3.0f) <= 3.0f * 1e-6f + 1e-6f);
    CHECK(largest_rise > 0.0f && largest_rise <= 0.05f * (1.0f + 1e-5f));
    /* Silence: the model expires after 5 ms and the force ramps to zero within 5 ms more (SPEC 10.5); the
     * watchdog (50 ms) then drops the drive to Idle. */
    for (i = 0; i < 700; i++) {
        cycle(-0.002f);
        if (now_us >= last_model_us + 5000 + 5000) CHECK(magnitude(force) == 0.0f);
    }
    CHECK(magnitude(force) == 0.0f);
    CHECK((voxhap_local_status(storage, sizeof storage) & 0x0002) == 0); /* ENABLED cleared */

    printf("voxhap-local C interface: %d checks, %d failed (storage %zu bytes, %u frames sent)\n", checks,
           failures, voxhap_local_storage_size(), frames_sent);
    return failures == 0 ? 0 : 1;
}
