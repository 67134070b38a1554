/* voxhap protocol codec: CRC-16/CCITT-FALSE, COBS, message encode/decode, the frame decoder (SPEC sections 3, 4). */
#include "voxhap.h"

#include <string.h>

/* The wire carries IEEE-754 binary32; this library assumes float is exactly that. */
typedef char voxhap_float_is_32_bits[(sizeof(float) == 4) ? 1 : -1];

const uint16_t voxhap_rate_table_hz[8] = {100, 200, 250, 500, 1000, 2000, 4000, 8000};

/* ------------------------------------------------------------------------------------------------ CRC */

/* T[i] = CRC register after shifting i << 8 through 8 rounds of poly 0x1021, every step kept to 16 bits. Computed
 * at compile time would need a generator; this table is the SPEC's recipe, checked in the unit tests against the
 * SPEC's listed entries (T[1] = 0x1021, T[2] = 0x2042, T[255] = 0x1EF0) and check value 0x29B1. */
static const uint16_t crc_table[256] = {
    0x0000, 0x1021, 0x2042, 0x3063, 0x4084, 0x50a5, 0x60c6, 0x70e7, 0x8108, 0x9129, 0xa14a, 0xb16b, 0xc18c, 0xd1ad,
    0xe1ce, 0xf1ef, 0x1231, 0x0210, 0x3273, 0x2252, 0x52b5, 0x4294, 0x72f7, 0x62d6, 0x9339, 0x8318, 0xb37b, 0xa35a,
    0xd3bd, 0xc39c, 0xf3ff, 0xe3de, 0x2462, 0x3443, 0x0420, 0x1401, 0x64e6, 0x74c7, 0x44a4, 0x5485, 0xa56a, 0xb54b,
    0x8528, 0x9509, 0xe5ee, 0xf5cf, 0xc5ac, 0xd58d, 0x3653, 0x2672, 0x1611, 0x0630, 0x76d7, 0x66f6, 0x5695, 0x46b4,
    0xb75b, 0xa77a, 0x9719, 0x8738, 0xf7df, 0xe7fe, 0xd79d, 0xc7bc, 0x48c4, 0x58e5, 0x6886, 0x78a7, 0x0840, 0x1861,
    0x2802, 0x3823, 0xc9cc, 0xd9ed, 0xe98e, 0xf9af, 0x8948, 0x9969, 0xa90a, 0xb92b, 0x5af5, 0x4ad4, 0x7ab7, 0x6a96,
    0x1a71, 0x0a50, 0x3a33, 0x2a12, 0xdbfd, 0xcbdc, 0xfbbf, 0xeb9e, 0x9b79, 0x8b58, 0xbb3b, 0xab1a, 0x6ca6, 0x7c87,
    0x4ce4, 0x5cc5, 0x2c22, 0x3c03, 0x0c60, 0x1c41, 0xedae, 0xfd8f, 0xcdec, 0xddcd, 0xad2a, 0xbd0b, 0x8d68, 0x9d49,
    0x7e97, 0x6eb6, 0x5ed5, 0x4ef4, 0x3e13, 0x2e32, 0x1e51, 0x0e70, 0xff9f, 0xefbe, 0xdfdd, 0xcffc, 0xbf1b, 0xaf3a,
    0x9f59, 0x8f78, 0x9188, 0x81a9, 0xb1ca, 0xa1eb, 0xd10c, 0xc12d, 0xf14e, 0xe16f, 0x1080, 0x00a1, 0x30c2, 0x20e3,
    0x5004, 0x4025, 0x7046, 0x6067, 0x83b9, 0x9398, 0xa3fb, 0xb3da, 0xc33d, 0xd31c, 0xe37f, 0xf35e, 0x02b1, 0x1290,
    0x22f3, 0x32d2, 0x4235, 0x5214, 0x6277, 0x7256, 0xb5ea, 0xa5cb, 0x95a8, 0x8589, 0xf56e, 0xe54f, 0xd52c, 0xc50d,
    0x34e2, 0x24c3, 0x14a0, 0x0481, 0x7466, 0x6447, 0x5424, 0x4405, 0xa7db, 0xb7fa, 0x8799, 0x97b8, 0xe75f, 0xf77e,
    0xc71d, 0xd73c, 0x26d3, 0x36f2, 0x0691, 0x16b0, 0x6657, 0x7676, 0x4615, 0x5634, 0xd94c, 0xc96d, 0xf90e, 0xe92f,
    0x99c8, 0x89e9, 0xb98a, 0xa9ab, 0x5844, 0x4865, 0x7806, 0x6827, 0x18c0, 0x08e1, 0x3882, 0x28a3, 0xcb7d, 0xdb5c,
    0xeb3f, 0xfb1e, 0x8bf9, 0x9bd8, 0xabbb, 0xbb9a, 0x4a75, 0x5a54, 0x6a37, 0x7a16, 0x0af1, 0x1ad0, 0x2ab3, 0x3a92,
    0xfd2e, 0xed0f, 0xdd6c, 0xcd4d, 0xbdaa, 0xad8b, 0x9de8, 0x8dc9, 0x7c26, 0x6c07, 0x5c64, 0x4c45, 0x3ca2, 0x2c83,
    0x1ce0, 0x0cc1, 0xef1f, 0xff3e, 0xcf5d, 0xdf7c, 0xaf9b, 0xbfba, 0x8fd9, 0x9ff8, 0x6e17, 0x7e36, 0x4e55, 0x5e74,
    0x2e93, 0x3eb2, 0x0ed1, 0x1ef0};

uint16_t voxhap_crc16_update(uint16_t crc, const uint8_t *data, size_t len) {
    size_t i;
    for (i = 0; i < len; i++) {
        crc = (uint16_t)((uint16_t)(crc << 8) ^ crc_table[(uint8_t)((crc >> 8) ^ data[i])]);
    }
    return crc;
}

uint16_t voxhap_crc16(const uint8_t *data, size_t len) { return voxhap_crc16_update(0xFFFFu, data, len); }

/* ------------------------------------------------------------------------------------------------ COBS */

size_t voxhap_cobs_encode(const uint8_t *in, size_t len, uint8_t *out, size_t out_cap) {
    size_t code_at = 0, w = 1, i;
    uint8_t code = 1;
    if (out_cap < len + len / 254u + 1u) {
        return 0;
    }
    for (i = 0; i < len; i++) {
        if (in[i] == 0) {
            out[code_at] = code;
            code_at = w++;
            code = 1;
        } else {
            out[w++] = in[i];
            code++;
            if (code == 0xFF) {
                out[code_at] = code;
                code_at = w++;
                code = 1;
            }
        }
    }
    out[code_at] = code;
    return w;
}

int voxhap_cobs_decode(const uint8_t *in, size_t len, uint8_t *out) {
    size_t r = 0, w = 0;
    while (r < len) {
        size_t code = in[r];
        size_t k;
        if (code == 0 || r + code > len) {
            return -1; /* a zero inside, or the delimiter came while this code still promised data */
        }
        /* Copy forwards: w <= r always, so out == in is safe. */
        for (k = 1; k < code; k++) {
            if (in[r + k] == 0) {
                return -1;
            }
            out[w++] = in[r + k];
        }
        r += code;
        if (r < len && code != 0xFF) {
            out[w++] = 0;
        }
    }
    return (int)w;
}

/* ------------------------------------------------------------------------------------------------ fields */

static uint32_t float_bits(float f) {
    uint32_t u;
    memcpy(&u, &f, sizeof u);
    return u;
}

static float bits_float(uint32_t u) {
    float f;
    memcpy(&f, &u, sizeof f);
    return f;
}

int voxhap_isfinite(float x) { return (float_bits(x) & 0x7F800000u) != 0x7F800000u; }

static int all_finite(const float *v, size_t n) {
    size_t i;
    for (i = 0; i < n; i++) {
        if (!voxhap_isfinite(v[i])) {
            return 0;
        }
    }
    return 1;
}

/* Printable ASCII (0x20..0x7E), then only zeros. */
static int label_ok(const char *label) {
    size_t i = 0;
    while (i < VOXHAP_LABEL_LEN && label[i] != 0) {
        uint8_t c = (uint8_t)label[i];
        if (c < 0x20u || c > 0x7Eu) {
            return 0;
        }
        i++;
    }
    for (; i < VOXHAP_LABEL_LEN; i++) {
        if (label[i] != 0) {
            return 0;
        }
    }
    return 1;
}

typedef struct {
    uint8_t *p;
    size_t n;
} writer;

static void w_u8(writer *w, uint8_t v) { w->p[w->n++] = v; }
static void w_u16(writer *w, uint16_t v) {
    w_u8(w, (uint8_t)(v & 0xFFu));
    w_u8(w, (uint8_t)(v >> 8));
}
static void w_u32(writer *w, uint32_t v) {
    w_u16(w, (uint16_t)(v & 0xFFFFu));
    w_u16(w, (uint16_t)(v >> 16));
}
static void w_u64(writer *w, uint64_t v) {
    w_u32(w, (uint32_t)(v & 0xFFFFFFFFu));
    w_u32(w, (uint32_t)(v >> 32));
}
static void w_f32(writer *w, float f) { w_u32(w, float_bits(f)); }
static void w_vec3(writer *w, const float v[3]) {
    w_f32(w, v[0]);
    w_f32(w, v[1]);
    w_f32(w, v[2]);
}
static void w_label(writer *w, const char *label) {
    memcpy(w->p + w->n, label, VOXHAP_LABEL_LEN);
    w->n += VOXHAP_LABEL_LEN;
}

static uint16_t r_u16(const uint8_t *p) { return (uint16_t)(p[0] | (uint16_t)(p[1] << 8)); }
static uint32_t r_u32(const uint8_t *p) { return (uint32_t)r_u16(p) | ((uint32_t)r_u16(p + 2) << 16); }
static uint64_t r_u64(const uint8_t *p) { return (uint64_t)r_u32(p) | ((uint64_t)r_u32(p + 4) << 32); }
static float r_f32(const uint8_t *p) { return bits_float(r_u32(p)); }
static void r_vec3(const uint8_t *p, float out[3]) {
    out[0] = r_f32(p);
    out[1] = r_f32(p + 4);
    out[2] = r_f32(p + 8);
}

/* Payload size of each type, or -1 for an unknown type of that direction. */
static int host_payload_len(uint8_t type) {
    switch (type) {
    case VOXHAP_HELLO: return 2;
    case VOXHAP_ENABLE: return 4;
    case VOXHAP_DISABLE: return 0;
    case VOXHAP_SET_FORCE: return 18;
    case VOXHAP_HEARTBEAT: return 4;
    case VOXHAP_CLEAR_FAULT: return 0;
    case VOXHAP_SET_STATE_RATE: return 2;
    default: return -1;
    }
}

static int device_payload_len(uint8_t type) {
    switch (type) {
    case VOXHAP_DEVICE_INFO: return 62;
    case VOXHAP_STATE: return 46;
    case VOXHAP_HEARTBEAT_REPLY: return 14;
    case VOXHAP_FAULT: return 11;
    case VOXHAP_REJECTED: return 2;
    default: return -1;
    }
}

static int device_info_ok(const voxhap_device_info *m) {
    int i;
    if (m->position_dof > 6u || m->force_dof > 6u || m->button_count > 16u) {
        return 0;
    }
    if (!label_ok(m->model) || !label_ok(m->serial_number)) {
        return 0;
    }
    if (!all_finite(m->workspace_min_m, 3) || !all_finite(m->workspace_max_m, 3)) {
        return 0;
    }
    for (i = 0; i < 3; i++) {
        if (!(m->workspace_min_m[i] <= m->workspace_max_m[i])) {
            return 0;
        }
    }
    if (!voxhap_isfinite(m->max_force_n) || !(m->max_force_n >= 0.0f)) {
        return 0;
    }
    return voxhap_isfinite(m->max_stiffness_n_per_m) && m->max_stiffness_n_per_m >= 0.0f;
}

/* ------------------------------------------------------------------------------------------------ encoders */

/* type ‖ payload (already in frame[0..n]) → CRC, COBS, delimiter into out. */
static size_t finish_frame(uint8_t *frame, size_t n, uint8_t *out, size_t out_cap) {
    uint16_t crc = voxhap_crc16(frame, n);
    size_t stuffed;
    frame[n++] = (uint8_t)(crc & 0xFFu);
    frame[n++] = (uint8_t)(crc >> 8);
    if (out_cap < n + 2u) {
        return 0;
    }
    stuffed = voxhap_cobs_encode(frame, n, out, out_cap - 1u);
    if (stuffed == 0) {
        return 0;
    }
    out[stuffed] = 0x00;
    return stuffed + 1u;
}

size_t voxhap_encode_host(const voxhap_host_msg *msg, uint8_t *out, size_t out_cap) {
    uint8_t frame[VOXHAP_MAX_FRAME_LEN];
    writer w;
    w.p = frame;
    w.n = 0;
    if (host_payload_len(msg->type) < 0) {
        return 0;
    }
    w_u8(&w, msg->type);
    switch (msg->type) {
    case VOXHAP_HELLO:
        w_u8(&w, msg->u.hello.major);
        w_u8(&w, msg->u.hello.minor);
        break;
    case VOXHAP_ENABLE: w_u32(&w, msg->u.enable_watchdog_timeout_us); break;
    case VOXHAP_SET_FORCE:
        if (!all_finite(msg->u.set_force.force_n, 3)) {
            return 0;
        }
        w_u32(&w, msg->u.set_force.sequence);
        w_vec3(&w, msg->u.set_force.force_n);
        w_u16(&w, msg->u.set_force.flags);
        break;
    case VOXHAP_HEARTBEAT: w_u32(&w, msg->u.heartbeat_counter); break;
    case VOXHAP_SET_STATE_RATE: w_u16(&w, msg->u.set_state_rate_hz); break;
    default: break; /* Disable, ClearFault: no payload */
    }
    return finish_frame(frame, w.n, out, out_cap);
}

size_t voxhap_encode_device(const voxhap_device_msg *msg, uint8_t *out, size_t out_cap) {
    uint8_t frame[VOXHAP_MAX_FRAME_LEN];
    writer w;
    w.p = frame;
    w.n = 0;
    w_u8(&w, msg->type);
    switch (msg->type) {
    case VOXHAP_DEVICE_INFO: {
        const voxhap_device_info *m = &msg->u.device_info;
        if (!device_info_ok(m)) {
            return 0;
        }
        w_u8(&w, m->version.major);
        w_u8(&w, m->version.minor);
        w_label(&w, m->model);
        w_label(&w, m->serial_number);
        w_u8(&w, m->position_dof);
        w_u8(&w, m->force_dof);
        w_u8(&w, m->button_count);
        w_u8(&w, m->supported_rates);
        w_vec3(&w, m->workspace_min_m);
        w_vec3(&w, m->workspace_max_m);
        w_f32(&w, m->max_force_n);
        w_f32(&w, m->max_stiffness_n_per_m);
        break;
    }
    case VOXHAP_STATE: {
        const voxhap_state *m = &msg->u.state;
        if (!all_finite(m->position_m, 3) || !all_finite(m->velocity_m_per_s, 3)) {
            return 0;
        }
        w_u32(&w, m->sequence);
        w_u64(&w, m->device_time_us);
        w_vec3(&w, m->position_m);
        w_vec3(&w, m->velocity_m_per_s);
        w_u32(&w, m->last_force_sequence);
        w_u16(&w, m->buttons);
        w_u16(&w, m->status);
        w_u16(&w, m->faults);
        break;
    }
    case VOXHAP_HEARTBEAT_REPLY:
        w_u32(&w, msg->u.heartbeat_reply.counter);
        w_u64(&w, msg->u.heartbeat_reply.device_time_us);
        w_u16(&w, msg->u.heartbeat_reply.status);
        break;
    case VOXHAP_FAULT:
        if (msg->u.fault.code > VOXHAP_FAULT_MAX) {
            return 0;
        }
        w_u8(&w, msg->u.fault.code);
        w_u16(&w, msg->u.fault.active_faults);
        w_u64(&w, msg->u.fault.device_time_us);
        break;
    case VOXHAP_REJECTED:
        w_u8(&w, msg->u.rejected.message_type);
        w_u8(&w, msg->u.rejected.reason);
        break;
    default: return 0;
    }
    return finish_frame(frame, w.n, out, out_cap);
}

/* ------------------------------------------------------------------------------------------------ parsers */

voxhap_result voxhap_parse_host(uint8_t type, const uint8_t *p, size_t len, voxhap_host_msg *out) {
    int expected = host_payload_len(type);
    if (expected < 0) {
        return VOXHAP_ERR_UNKNOWN_TYPE;
    }
    if ((size_t)expected != len) {
        return VOXHAP_ERR_BAD_LENGTH;
    }
    memset(out, 0, sizeof *out);
    out->type = type;
    switch (type) {
    case VOXHAP_HELLO:
        out->u.hello.major = p[0];
        out->u.hello.minor = p[1];
        break;
    case VOXHAP_ENABLE: out->u.enable_watchdog_timeout_us = r_u32(p); break;
    case VOXHAP_SET_FORCE:
        out->u.set_force.sequence = r_u32(p);
        r_vec3(p + 4, out->u.set_force.force_n);
        out->u.set_force.flags = r_u16(p + 16);
        if (!all_finite(out->u.set_force.force_n, 3)) {
            return VOXHAP_ERR_INVALID_VALUE;
        }
        break;
    case VOXHAP_HEARTBEAT: out->u.heartbeat_counter = r_u32(p); break;
    case VOXHAP_SET_STATE_RATE: out->u.set_state_rate_hz = r_u16(p); break;
    default: break;
    }
    return VOXHAP_OK;
}

voxhap_result voxhap_parse_device(uint8_t type, const uint8_t *p, size_t len, voxhap_device_msg *out) {
    int expected = device_payload_len(type);
    if (expected < 0) {
        return VOXHAP_ERR_UNKNOWN_TYPE;
    }
    if ((size_t)expected != len) {
        return VOXHAP_ERR_BAD_LENGTH;
    }
    memset(out, 0, sizeof *out);
    out->type = type;
    switch (type) {
    case VOXHAP_DEVICE_INFO: {
        voxhap_device_info *m = &out->u.device_info;
        m->version.major = p[0];
        m->version.minor = p[1];
        memcpy(m->model, p + 2, VOXHAP_LABEL_LEN);
        memcpy(m->serial_number, p + 14, VOXHAP_LABEL_LEN);
        m->position_dof = p[26];
        m->force_dof = p[27];
        m->button_count = p[28];
        m->supported_rates = p[29];
        r_vec3(p + 30, m->workspace_min_m);
        r_vec3(p + 42, m->workspace_max_m);
        m->max_force_n = r_f32(p + 54);
        m->max_stiffness_n_per_m = r_f32(p + 58);
        if (!device_info_ok(m)) {
            return VOXHAP_ERR_INVALID_VALUE;
        }
        break;
    }
    case VOXHAP_STATE: {
        voxhap_state *m = &out->u.state;
        m->sequence = r_u32(p);
        m->device_time_us = r_u64(p + 4);
        r_vec3(p + 12, m->position_m);
        r_vec3(p + 24, m->velocity_m_per_s);
        m->last_force_sequence = r_u32(p + 36);
        m->buttons = r_u16(p + 40);
        m->status = r_u16(p + 42);
        m->faults = r_u16(p + 44);
        if (!all_finite(m->position_m, 3) || !all_finite(m->velocity_m_per_s, 3)) {
            return VOXHAP_ERR_INVALID_VALUE;
        }
        break;
    }
    case VOXHAP_HEARTBEAT_REPLY:
        out->u.heartbeat_reply.counter = r_u32(p);
        out->u.heartbeat_reply.device_time_us = r_u64(p + 4);
        out->u.heartbeat_reply.status = r_u16(p + 12);
        break;
    case VOXHAP_FAULT:
        out->u.fault.code = p[0];
        out->u.fault.active_faults = r_u16(p + 1);
        out->u.fault.device_time_us = r_u64(p + 3);
        if (out->u.fault.code > VOXHAP_FAULT_MAX) {
            return VOXHAP_ERR_INVALID_VALUE;
        }
        break;
    case VOXHAP_REJECTED:
        out->u.rejected.message_type = p[0];
        out->u.rejected.reason = p[1];
        break;
    default: break;
    }
    return VOXHAP_OK;
}

/* ------------------------------------------------------------------------------------------------ decoder */

void voxhap_decoder_init(voxhap_decoder *d) { memset(d, 0, sizeof *d); }

/* Collects one byte; at a delimiter unstuffs and checks length and CRC. Returns -1 (no frame), a voxhap_result
 * error (counted), or VOXHAP_OK with *frame_len set (frame in d->buf: type ‖ payload, CRC stripped). */
static int collect(voxhap_decoder *d, uint8_t byte, size_t *frame_len) {
    size_t n;
    int unstuffed;
    uint16_t crc;
    if (byte != 0) {
        if (d->len < VOXHAP_MAX_STUFFED_LEN) {
            d->buf[d->len++] = byte;
        } else {
            d->overflow = 1;
        }
        return -1;
    }
    n = d->len;
    d->len = 0;
    if (d->overflow) {
        d->overflow = 0;
        d->stats.oversize++;
        return VOXHAP_ERR_OVERSIZE;
    }
    if (n == 0) {
        return -1; /* two delimiters in a row: idle filler */
    }
    unstuffed = voxhap_cobs_decode(d->buf, n, d->buf);
    if (unstuffed < 0) {
        d->stats.cobs_errors++;
        return VOXHAP_ERR_COBS;
    }
    if ((size_t)unstuffed > VOXHAP_MAX_FRAME_LEN) {
        d->stats.oversize++;
        return VOXHAP_ERR_OVERSIZE;
    }
    if (unstuffed < 3) {
        d->stats.too_short++;
        return VOXHAP_ERR_TOO_SHORT;
    }
    crc = voxhap_crc16(d->buf, (size_t)unstuffed - 2u);
    if (d->buf[unstuffed - 2] != (uint8_t)(crc & 0xFFu) || d->buf[unstuffed - 1] != (uint8_t)(crc >> 8)) {
        d->stats.crc_errors++;
        return VOXHAP_ERR_CRC;
    }
    *frame_len = (size_t)unstuffed - 2u;
    return VOXHAP_OK;
}

static int count(voxhap_decoder *d, voxhap_result r) {
    switch (r) {
    case VOXHAP_OK: d->stats.frames_ok++; break;
    case VOXHAP_ERR_UNKNOWN_TYPE: d->stats.unknown_type++; break;
    case VOXHAP_ERR_BAD_LENGTH: d->stats.bad_length++; break;
    default: d->stats.invalid_value++; break;
    }
    return (int)r;
}

int voxhap_decoder_push_host(voxhap_decoder *d, uint8_t byte, voxhap_host_msg *out) {
    size_t n = 0;
    int r = collect(d, byte, &n);
    if (r != VOXHAP_OK) {
        return r;
    }
    return count(d, voxhap_parse_host(d->buf[0], d->buf + 1, n - 1u, out));
}

int voxhap_decoder_push_device(voxhap_decoder *d, uint8_t byte, voxhap_device_msg *out) {
    size_t n = 0;
    int r = collect(d, byte, &n);
    if (r != VOXHAP_OK) {
        return r;
    }
    return count(d, voxhap_parse_device(d->buf[0], d->buf + 1, n - 1u, out));
}
