/*
 * voxhap device protocol 1.1, device side, in portable C99 (protocol/SPEC.md is normative).
 *
 * Three layers, each usable alone:
 *   1. Codec: CRC-16/CCITT-FALSE, COBS, and encode/decode of every message (both directions).
 *   2. Session: the device state machine of SPEC section 6 (session, drive Idle/Enabled/Faulted, watchdog, force
 *      clamp, status and fault bits, State scheduling, an 8-message outbox). Pure: time is passed in.
 *   3. Firmware: a control cycle that drives the session through a small HAL a board port fills in (clock,
 *      UART bytes in and out, sensing, motor output), adds a force rise-rate (slew) limit, and frames replies.
 *
 * No dynamic allocation, no recursion, no global state: every object is a plain struct the caller owns. Floats are
 * IEEE-754 binary32 (float) only: on the wire, in the clamp and in the slew limit. Finiteness is checked on the bit
 * pattern, so the library stays correct even if a port compiles it with -ffast-math (which breaks isfinite).
 * Call everything that touches one session from one context (or guard it with a critical section).
 */
#ifndef VOXHAP_H
#define VOXHAP_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* ------------------------------------------------------------------------------------------------ constants */

#define VOXHAP_VERSION_MAJOR 1u
/* 1.1: every mandatory rule of 1.1 is a 1.0 rule; this library does not implement the optional local-model
 * capability (SPEC section 10), so it never sets status bit 6 and drops LocalModel (0x08) as an unknown type, and a
 * 1.1 host drives it through SetForce (SPEC section 2, "Mixed minors"). */
#define VOXHAP_VERSION_MINOR 1u

/* Message types (SPEC section 3). Host to device 0x01..0x7F, device to host 0x81..0xFF. */
#define VOXHAP_HELLO 0x01u
#define VOXHAP_ENABLE 0x02u
#define VOXHAP_DISABLE 0x03u
#define VOXHAP_SET_FORCE 0x04u
#define VOXHAP_HEARTBEAT 0x05u
#define VOXHAP_CLEAR_FAULT 0x06u
#define VOXHAP_SET_STATE_RATE 0x07u
#define VOXHAP_DEVICE_INFO 0x81u
#define VOXHAP_STATE 0x82u
#define VOXHAP_HEARTBEAT_REPLY 0x83u
#define VOXHAP_FAULT 0x84u
#define VOXHAP_REJECTED 0x85u

#define VOXHAP_MAX_PAYLOAD_LEN 62u
#define VOXHAP_MAX_FRAME_LEN 65u       /* type + payload + 2 CRC bytes, unstuffed */
#define VOXHAP_MAX_STUFFED_LEN 66u     /* + 1 COBS code byte */
#define VOXHAP_MAX_WIRE_FRAME_LEN 67u  /* + the 0x00 delimiter: the buffer a sender needs */

/* SetForce flags. */
#define VOXHAP_FORCE_REQUEST_STATE 0x0001u

/* Status bits (SPEC section 6.1). */
#define VOXHAP_STATUS_SESSION_OPEN 0x0001u
#define VOXHAP_STATUS_ENABLED 0x0002u
#define VOXHAP_STATUS_FAULTED 0x0004u
#define VOXHAP_STATUS_WATCHDOG_TRIPPED 0x0008u
#define VOXHAP_STATUS_FORCE_CLAMPED 0x0010u
#define VOXHAP_STATUS_LOCKSTEP 0x0020u

/* Fault codes (SPEC section 3.2). Code 0 does not latch; 1..15 do. */
#define VOXHAP_FAULT_WATCHDOG_EXPIRED 0u
#define VOXHAP_FAULT_EMERGENCY_STOP 1u
#define VOXHAP_FAULT_OVER_TEMPERATURE 2u
#define VOXHAP_FAULT_OVER_CURRENT 3u
#define VOXHAP_FAULT_ENCODER 4u
#define VOXHAP_FAULT_AMPLIFIER 5u
#define VOXHAP_FAULT_SUPPLY_VOLTAGE 6u
#define VOXHAP_FAULT_INTERNAL 7u
#define VOXHAP_FAULT_MAX 15u

/* Reject reasons. */
#define VOXHAP_REJECT_NO_SESSION 1u
#define VOXHAP_REJECT_VERSION_MISMATCH 2u
#define VOXHAP_REJECT_FAULTED 3u
#define VOXHAP_REJECT_INVALID_ARGUMENT 4u

/* Watchdog (SPEC section 6.5), microseconds. */
#define VOXHAP_DEFAULT_WATCHDOG_TIMEOUT_US 50000u
#define VOXHAP_MIN_WATCHDOG_TIMEOUT_US 1000u
#define VOXHAP_MAX_WATCHDOG_TIMEOUT_US 1000000u

/* Supported state rates: bit n of DeviceInfo.supported_rates is voxhap_rate_table_hz[n]. */
#define VOXHAP_RATE_100 0x01u
#define VOXHAP_RATE_200 0x02u
#define VOXHAP_RATE_250 0x04u
#define VOXHAP_RATE_500 0x08u
#define VOXHAP_RATE_1000 0x10u
#define VOXHAP_RATE_2000 0x20u
#define VOXHAP_RATE_4000 0x40u
#define VOXHAP_RATE_8000 0x80u
extern const uint16_t voxhap_rate_table_hz[8];

#define VOXHAP_OUTBOX_CAPACITY 8u
#define VOXHAP_LABEL_LEN 12u

/* ------------------------------------------------------------------------------------------------ messages */

typedef struct {
    uint8_t major, minor;
} voxhap_version;

typedef struct {
    uint8_t type; /* VOXHAP_HELLO ... VOXHAP_SET_STATE_RATE */
    union {
        voxhap_version hello;
        uint32_t enable_watchdog_timeout_us;
        struct {
            uint32_t sequence;
            float force_n[3];
            uint16_t flags;
        } set_force;
        uint32_t heartbeat_counter;
        uint16_t set_state_rate_hz;
    } u;
} voxhap_host_msg;

typedef struct {
    voxhap_version version;
    char model[VOXHAP_LABEL_LEN];         /* printable ASCII, zero padded; need not be zero terminated */
    char serial_number[VOXHAP_LABEL_LEN]; /* idem */
    uint8_t position_dof, force_dof, button_count, supported_rates;
    float workspace_min_m[3], workspace_max_m[3];
    float max_force_n, max_stiffness_n_per_m;
} voxhap_device_info;

typedef struct {
    uint32_t sequence;
    uint64_t device_time_us;
    float position_m[3];
    float velocity_m_per_s[3];
    uint32_t last_force_sequence;
    uint16_t buttons, status, faults;
} voxhap_state;

typedef struct {
    uint8_t type; /* VOXHAP_DEVICE_INFO ... VOXHAP_REJECTED */
    union {
        voxhap_device_info device_info;
        voxhap_state state;
        struct {
            uint32_t counter;
            uint64_t device_time_us;
            uint16_t status;
        } heartbeat_reply;
        struct {
            uint8_t code;
            uint16_t active_faults;
            uint64_t device_time_us;
        } fault;
        struct {
            uint8_t message_type, reason;
        } rejected;
    } u;
} voxhap_device_msg;

/* ------------------------------------------------------------------------------------------------ codec */

/* Why a frame was dropped; VOXHAP_OK (0) for an accepted one. Checked in this order (SPEC section 4.4). */
typedef enum {
    VOXHAP_OK = 0,
    VOXHAP_ERR_COBS = 1,
    VOXHAP_ERR_OVERSIZE = 2,
    VOXHAP_ERR_TOO_SHORT = 3,
    VOXHAP_ERR_CRC = 4,
    VOXHAP_ERR_UNKNOWN_TYPE = 5,
    VOXHAP_ERR_BAD_LENGTH = 6,
    VOXHAP_ERR_INVALID_VALUE = 7,
    VOXHAP_ERR_BUFFER = 8 /* encode: output buffer too small, or a message that must not be sent (NaN, bad label) */
} voxhap_result;

/* CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final XOR) over len bytes. */
uint16_t voxhap_crc16(const uint8_t *data, size_t len);
/* Continues a CRC: voxhap_crc16(a ‖ b) == voxhap_crc16_update(voxhap_crc16(a), b). */
uint16_t voxhap_crc16_update(uint16_t crc, const uint8_t *data, size_t len);

/* COBS-stuffs len bytes into out (capacity out_cap, at least len + len/254 + 1); returns the stuffed length, or 0
 * if out is too small. The output has no 0x00; the caller appends the delimiter. */
size_t voxhap_cobs_encode(const uint8_t *in, size_t len, uint8_t *out, size_t out_cap);
/* Unstuffs len stuffed bytes (no delimiter) into out (may equal in); returns the unstuffed length, or -1 when the
 * chain of code bytes does not end exactly on the last byte, or a 0x00 is among them. */
int voxhap_cobs_decode(const uint8_t *in, size_t len, uint8_t *out);

/* Complete serial frames, delimiter included. Encoders return the wire length (at most 67), or 0 when out_cap is
 * too small or the message must not be sent (a non-finite float, a bad label, a field out of range). */
size_t voxhap_encode_host(const voxhap_host_msg *msg, uint8_t *out, size_t out_cap);
size_t voxhap_encode_device(const voxhap_device_msg *msg, uint8_t *out, size_t out_cap);

/* Payload-level decoders, given the unstuffed frame without the CRC check (type ‖ payload). */
voxhap_result voxhap_parse_host(uint8_t type, const uint8_t *payload, size_t len, voxhap_host_msg *out);
voxhap_result voxhap_parse_device(uint8_t type, const uint8_t *payload, size_t len, voxhap_device_msg *out);

/* Drop counters, one per reason, plus accepted frames. */
typedef struct {
    uint32_t frames_ok, cobs_errors, oversize, too_short, crc_errors, unknown_type, bad_length, invalid_value;
} voxhap_decoder_stats;

/* A byte-at-a-time frame receiver: 66 bytes of buffer. Zero-initialise it, or call voxhap_decoder_init. */
typedef struct {
    uint8_t buf[VOXHAP_MAX_STUFFED_LEN];
    uint8_t len;
    uint8_t overflow;
    voxhap_decoder_stats stats;
} voxhap_decoder;

void voxhap_decoder_init(voxhap_decoder *d);
/* Feeds one byte. Returns -1 while no frame ended (and for an empty frame, i.e. idle filler), VOXHAP_OK with *out
 * filled when a host-to-device frame was accepted, or the reason a frame was dropped (already counted). */
int voxhap_decoder_push_host(voxhap_decoder *d, uint8_t byte, voxhap_host_msg *out);
/* The same for device-to-host frames (a host, or a test). */
int voxhap_decoder_push_device(voxhap_decoder *d, uint8_t byte, voxhap_device_msg *out);

/* Bit-level finiteness (not NaN, not infinite), immune to -ffast-math. */
int voxhap_isfinite(float x);

/* ------------------------------------------------------------------------------------------------ session */

typedef enum { VOXHAP_IDLE = 0, VOXHAP_ENABLED = 1, VOXHAP_FAULTED = 2 } voxhap_drive;

/* What the device senses this cycle, device frame. */
typedef struct {
    float position_m[3];
    float velocity_m_per_s[3];
    uint16_t buttons;
} voxhap_sample;

typedef struct {
    uint32_t forces_ignored;   /* SetForce not applied: session closed, not Enabled */
    uint32_t watchdog_trips;   /* times the watchdog dropped the force */
    uint32_t states_queued;    /* State messages queued */
    uint32_t outbox_overflows; /* replies dropped because the outbox was full (newest dropped) */
} voxhap_session_stats;

typedef struct {
    voxhap_device_info info;
    uint8_t session_open;
    uint8_t drive; /* voxhap_drive */
    uint8_t force_clamped;
    uint8_t watchdog_tripped;
    uint8_t state_requested;
    uint16_t faults; /* latched codes >= 1, bit 0 always 0 */
    uint16_t state_rate_hz; /* 0 = lockstep */
    uint32_t watchdog_timeout_us;
    uint32_t last_force_sequence;
    uint32_t state_sequence;
    uint64_t last_force_us;
    uint64_t next_state_us;
    float force_n[3]; /* the clamped force in force while Enabled */
    voxhap_device_msg outbox[VOXHAP_OUTBOX_CAPACITY];
    uint8_t outbox_head, outbox_len;
    voxhap_session_stats stats;
} voxhap_session;

/* A powered-up device: session closed, Idle, zero force. info is copied; it is what Hello is answered with, and its
 * max_force_n and supported_rates are enforced. Returns VOXHAP_OK, or VOXHAP_ERR_INVALID_VALUE for an info that
 * could not be sent (bad label, non-finite or negative limits, min > max, dof > 6, buttons > 16). */
voxhap_result voxhap_session_init(voxhap_session *s, const voxhap_device_info *info);
/* Handles one decoded host message received at now_us; replies are queued. */
void voxhap_session_on_message(voxhap_session *s, const voxhap_host_msg *msg, uint64_t now_us);
/* Reports a fault the firmware detected. Code 0 (watchdog) drops to Idle; 1..15 latch (Faulted until ClearFault);
 * larger codes are reported as INTERNAL. Sent whether or not a session is open. */
void voxhap_session_raise_fault(voxhap_session *s, uint8_t code, uint64_t now_us);
/* One control cycle at now_us: runs the watchdog, checks the sample (a non-finite one raises ENCODER once and sends
 * no State), queues a State when due, and writes the force to apply (zero unless Enabled) to force_out. */
void voxhap_session_poll(voxhap_session *s, uint64_t now_us, const voxhap_sample *sample, float force_out[3]);
/* The next queued reply, oldest first: returns 1 and fills *out, or 0 when the outbox is empty. */
int voxhap_session_poll_transmit(voxhap_session *s, voxhap_device_msg *out);
/* Status bits as sent in State and HeartbeatReply. */
uint16_t voxhap_session_status(const voxhap_session *s);

/* Scales f down to magnitude max_n if longer, keeping its direction; returns 1 if it scaled. f32 only (no double):
 * the result obeys |out| <= max_n * (1 + 1e-6) for every finite input, including components near FLT_MAX. */
int voxhap_clamp_magnitude(const float f[3], float max_n, float out[3]);

/* ------------------------------------------------------------------------------------------------ firmware */

/* What a board port fills in. ctx is passed back to every call. Every function must return promptly (no
 * blocking): the whole control cycle runs inside one control period. */
typedef struct {
    void *ctx;
    /* Microseconds since start-up, never going backwards (a 64-bit extension of a hardware timer). */
    uint64_t (*now_us)(void *ctx);
    /* Up to cap received bytes, without blocking; returns how many were copied (0 when none). */
    size_t (*uart_read)(void *ctx, uint8_t *buf, size_t cap);
    /* Queues len bytes for transmission (may block only as long as a 67-byte frame takes on the line). */
    void (*uart_write)(void *ctx, const uint8_t *buf, size_t len);
    /* Reads the encoders and fills position and velocity in metres and m/s, device frame, and the buttons. */
    void (*read_sample)(void *ctx, voxhap_sample *out);
    /* Applies force_n (newtons on the handle, device frame): Jacobian transpose to joint torques, then currents. */
    void (*write_force)(void *ctx, const float force_n[3]);
    /* Optional (NULL = none): bit n set = hardware fault code n (1..15) present now (e-stop, over-current, ...). */
    uint16_t (*read_faults)(void *ctx);
    /* Optional (NULL = none): told of every accepted host message, before the session handles it (logging). */
    void (*on_message)(void *ctx, const voxhap_host_msg *msg, uint64_t now_us);
    /* Optional (NULL = none): told of every reply just before it is framed and written (logging). */
    void (*on_reply)(void *ctx, const voxhap_device_msg *msg, uint64_t now_us);
} voxhap_hal;

typedef struct {
    voxhap_hal hal;
    voxhap_session session;
    voxhap_decoder decoder;
    float max_rise_n_per_s; /* slew limit on the rise of |applied force|; 0 = none; drops are never limited */
    float applied_n[3];     /* what write_force got last */
    uint64_t last_control_us;
    uint16_t hw_faults_seen;
    uint32_t messages;
} voxhap_fw;

/* Sets up session and decoder; max_rise_n_per_s as in voxhap_fw. Writes nothing. */
voxhap_result voxhap_fw_init(voxhap_fw *fw, const voxhap_hal *hal, const voxhap_device_info *info,
                             float max_rise_n_per_s);
/* Call once, as soon as the UART is configured: sends the lone 0x00 of SPEC section 4.3 and writes zero force. */
void voxhap_fw_start(voxhap_fw *fw);
/* Receive path: drains the UART into the decoder and hands each accepted message to the session. Returns the
 * number of messages handled. */
uint32_t voxhap_fw_receive(voxhap_fw *fw);
/* Control cycle: hardware faults, sample, session poll (watchdog, State), clamp, slew limit, write_force, then
 * transmits every queued reply (a 0x00 before each DeviceInfo). Call at the control rate (1 kHz or faster), and
 * also right after voxhap_fw_receive returned > 0 if you want the lowest reply latency. */
void voxhap_fw_control(voxhap_fw *fw);
/* voxhap_fw_receive then voxhap_fw_control. */
void voxhap_fw_tick(voxhap_fw *fw);

/* Limits the rise of |f| relative to |prev| to max_rise_n (keeping f's direction); falls are not limited. */
void voxhap_slew_limit(const float prev[3], const float f[3], float max_rise_n, float out[3]);

#ifdef __cplusplus
}
#endif

#endif /* VOXHAP_H */
