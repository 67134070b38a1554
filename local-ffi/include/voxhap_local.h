/*
 * voxhap_local.h: the device side of voxhap's local-model capability (protocol/SPEC.md section 10) for a
 * firmware written in C. Link libvoxhap_local_ffi.a (local-ffi, a no_std Rust static library: no
 * allocation, no C library calls, no threads) and, on most toolchains, libm.
 *
 * One device lives in storage the caller provides: at least voxhap_local_storage_size() bytes aligned to
 * voxhap_local_storage_align() (a static array of uint64_t is usually right; check both at start-up). It holds
 * the frame decoder, the protocol session (watchdog, State and LocalState frames) and the local loop (solve,
 * coupling, clamp, ramps, slew limit, expiry). It announces protocol 1.1 with the LOCAL_MODEL capability.
 *
 * Every call takes the storage and its length; none blocks, allocates or keeps a pointer it was given other
 * than the storage. Call voxhap_local_receive and voxhap_local_step from the same context (or guard them).
 * Functions return VOXHAP_LOCAL_OK (0) or a count, or a negative VOXHAP_LOCAL_E* code.
 *
 * Use (docs/local-model.md, "Linking from C"):
 *   static uint64_t storage[VOXHAP_LOCAL_STORAGE_WORDS];
 *   voxhap_local_init(storage, sizeof storage, &info, 100);          // 10 kHz control loop
 *   uart_write_byte(0);                                               // SPEC 4.3: a delimiter at start-up
 *   receive path:  voxhap_local_receive(storage, sizeof storage, bytes, n, now_us);
 *   control loop:  voxhap_local_step(storage, sizeof storage, now_us, pos, vel, buttons, force);
 *                  apply force; then while ((n = voxhap_local_transmit(storage, sizeof storage, out,
 *                  sizeof out)) > 0) uart_write(out, n);
 */
#ifndef VOXHAP_LOCAL_H
#define VOXHAP_LOCAL_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define VOXHAP_LOCAL_OK 0
#define VOXHAP_LOCAL_ENULL (-1)    /* a pointer argument was null */
#define VOXHAP_LOCAL_ESTORAGE (-2) /* storage too small or misaligned */
#define VOXHAP_LOCAL_EINFO (-3)    /* invalid device description */
#define VOXHAP_LOCAL_EINIT (-4)    /* storage holds no initialised device */
#define VOXHAP_LOCAL_EBUFFER (-5)  /* output buffer smaller than VOXHAP_LOCAL_MAX_FRAME */

/* Largest frame voxhap_local_transmit writes (SPEC 4.2: 67 bytes with the delimiter). */
#define VOXHAP_LOCAL_MAX_FRAME 67u

/* A size that holds one device on 32- and 64-bit targets, in uint64_t words; voxhap_local_storage_size() is
 * the truth (the C test checks this is enough on the host). */
#define VOXHAP_LOCAL_STORAGE_WORDS 512u

/* Status bit 6 (SPEC 6.1): the device has the local-model capability. */
#define VOXHAP_LOCAL_STATUS_LOCAL_MODEL 0x0040u

/* DeviceInfo (SPEC 3.2), as the firmware describes its arm. */
typedef struct {
    uint8_t model[12];         /* printable ASCII, zero-padded */
    uint8_t serial_number[12]; /* printable ASCII, zero-padded */
    uint8_t position_dof;      /* 0..6 (3 for local models) */
    uint8_t force_dof;         /* 0..6 */
    uint8_t button_count;      /* 0..16 */
    uint8_t supported_rates;   /* bit set over SPEC's rate table: bit 3 500 Hz, bit 4 1000 Hz, ... */
    float workspace_min_m[3];
    float workspace_max_m[3];
    float max_force_n;           /* the device's clamp, N, >= 0 */
    float max_stiffness_n_per_m; /* >= 0 */
} voxhap_local_info;

size_t voxhap_local_storage_size(void);
size_t voxhap_local_storage_align(void);
size_t voxhap_local_max_frame(void);

/* A powered-up device in storage: session closed, drive idle, zero force. period_us: the control period the
 * loop assumes for its first cycle (0: 100 us); later cycles use the times passed to voxhap_local_step. */
int32_t voxhap_local_init(void *storage, size_t len, const voxhap_local_info *info, uint32_t period_us);

/* Bytes from the host (serial framing), at device time now_us. Returns the number of whole messages taken. */
int32_t voxhap_local_receive(void *storage, size_t len, const uint8_t *bytes, size_t n, uint64_t now_us);

/* One control cycle: writes the force to apply (N, device frame) to force_n[3] (zero on any error). */
int32_t voxhap_local_step(void *storage, size_t len, uint64_t now_us, const float position_m[3],
                          const float velocity_m_per_s[3], uint16_t buttons, float force_n[3]);

/* The next frame for the host, with its delimiter, into out (>= VOXHAP_LOCAL_MAX_FRAME bytes). Returns its
 * length, 0 when nothing is queued. Call until 0 after every cycle. */
int32_t voxhap_local_transmit(void *storage, size_t len, uint8_t *out, size_t out_len);

/* The status bits (SPEC 6.1), or a negative code. */
int32_t voxhap_local_status(void *storage, size_t len);

#ifdef __cplusplus
}
#endif

#endif /* VOXHAP_LOCAL_H */
