/* The device state machine of SPEC section 6: session, drive, watchdog, clamp, status and faults, State schedule. */
#include "voxhap.h"

#include <math.h>
#include <string.h>

static void send(voxhap_session *s, const voxhap_device_msg *m) {
    if (s->outbox_len == VOXHAP_OUTBOX_CAPACITY) {
        s->stats.outbox_overflows++; /* newest dropped (SPEC section 6.7) */
        return;
    }
    s->outbox[(s->outbox_head + s->outbox_len) % VOXHAP_OUTBOX_CAPACITY] = *m;
    s->outbox_len++;
}

static void reject(voxhap_session *s, uint8_t type, uint8_t reason) {
    voxhap_device_msg m;
    memset(&m, 0, sizeof m);
    m.type = VOXHAP_REJECTED;
    m.u.rejected.message_type = type;
    m.u.rejected.reason = reason;
    send(s, &m);
}

static void zero3(float v[3]) { v[0] = v[1] = v[2] = 0.0f; }

static void go_idle(voxhap_session *s) {
    if (s->drive == VOXHAP_ENABLED) {
        s->drive = VOXHAP_IDLE;
    }
    zero3(s->force_n);
}

voxhap_result voxhap_session_init(voxhap_session *s, const voxhap_device_info *info) {
    voxhap_device_msg probe;
    uint8_t scratch[VOXHAP_MAX_WIRE_FRAME_LEN];
    memset(s, 0, sizeof *s);
    s->info = *info;
    s->drive = VOXHAP_IDLE;
    s->watchdog_timeout_us = VOXHAP_DEFAULT_WATCHDOG_TIMEOUT_US;
    /* The info must be sendable (labels, finite limits, ranges): the encoder checks it all. */
    memset(&probe, 0, sizeof probe);
    probe.type = VOXHAP_DEVICE_INFO;
    probe.u.device_info = *info;
    if (voxhap_encode_device(&probe, scratch, sizeof scratch) == 0) {
        return VOXHAP_ERR_INVALID_VALUE;
    }
    return VOXHAP_OK;
}

uint16_t voxhap_session_status(const voxhap_session *s) {
    uint16_t st = 0;
    if (s->session_open) st |= VOXHAP_STATUS_SESSION_OPEN;
    if (s->drive == VOXHAP_ENABLED) st |= VOXHAP_STATUS_ENABLED;
    if (s->drive == VOXHAP_FAULTED) st |= VOXHAP_STATUS_FAULTED;
    if (s->watchdog_tripped) st |= VOXHAP_STATUS_WATCHDOG_TRIPPED;
    /* "the force being applied was scaled down": nothing is applied outside Enabled */
    if (s->force_clamped && s->drive == VOXHAP_ENABLED) st |= VOXHAP_STATUS_FORCE_CLAMPED;
    if (s->state_rate_hz == 0) st |= VOXHAP_STATUS_LOCKSTEP;
    return st;
}

static int rate_supported(const voxhap_session *s, uint16_t hz) {
    unsigned i;
    for (i = 0; i < 8u; i++) {
        if ((s->info.supported_rates & (1u << i)) && voxhap_rate_table_hz[i] == hz) {
            return 1;
        }
    }
    return 0;
}

static void enable(voxhap_session *s, uint32_t requested_us, uint64_t now_us) {
    uint32_t timeout_us = requested_us;
    if (s->drive == VOXHAP_FAULTED) {
        reject(s, VOXHAP_ENABLE, VOXHAP_REJECT_FAULTED);
        return;
    }
    if (timeout_us == 0) {
        timeout_us = VOXHAP_DEFAULT_WATCHDOG_TIMEOUT_US;
    } else if (timeout_us < VOXHAP_MIN_WATCHDOG_TIMEOUT_US || timeout_us > VOXHAP_MAX_WATCHDOG_TIMEOUT_US) {
        reject(s, VOXHAP_ENABLE, VOXHAP_REJECT_INVALID_ARGUMENT);
        return;
    }
    s->drive = VOXHAP_ENABLED;
    s->watchdog_timeout_us = timeout_us;
    s->last_force_us = now_us;
    zero3(s->force_n); /* zero until the next SetForce */
    s->force_clamped = 0;
    s->watchdog_tripped = 0;
}

static void set_force(voxhap_session *s, const voxhap_host_msg *m, uint64_t now_us) {
    s->last_force_sequence = m->u.set_force.sequence;
    if (s->state_rate_hz == 0 || (m->u.set_force.flags & VOXHAP_FORCE_REQUEST_STATE)) {
        s->state_requested = 1; /* lockstep: exactly one State per SetForce, whatever the flag */
    }
    if (s->drive != VOXHAP_ENABLED || !voxhap_isfinite(m->u.set_force.force_n[0]) ||
        !voxhap_isfinite(m->u.set_force.force_n[1]) || !voxhap_isfinite(m->u.set_force.force_n[2])) {
        s->stats.forces_ignored++;
        return;
    }
    s->force_clamped = (uint8_t)voxhap_clamp_magnitude(m->u.set_force.force_n, s->info.max_force_n, s->force_n);
    s->last_force_us = now_us; /* only an applied SetForce feeds the watchdog */
}

void voxhap_session_on_message(voxhap_session *s, const voxhap_host_msg *m, uint64_t now_us) {
    if (m->type == VOXHAP_HELLO) {
        voxhap_device_msg info;
        memset(&info, 0, sizeof info);
        info.type = VOXHAP_DEVICE_INFO;
        info.u.device_info = s->info;
        send(s, &info);
        go_idle(s); /* a Hello always starts over; Faulted stays Faulted */
        s->state_rate_hz = 0;
        s->watchdog_timeout_us = VOXHAP_DEFAULT_WATCHDOG_TIMEOUT_US;
        s->session_open = (uint8_t)(m->u.hello.major == s->info.version.major);
        if (!s->session_open) {
            reject(s, VOXHAP_HELLO, VOXHAP_REJECT_VERSION_MISMATCH);
        }
        return;
    }
    if (m->type == VOXHAP_HEARTBEAT) {
        voxhap_device_msg r;
        memset(&r, 0, sizeof r);
        r.type = VOXHAP_HEARTBEAT_REPLY;
        r.u.heartbeat_reply.counter = m->u.heartbeat_counter;
        r.u.heartbeat_reply.device_time_us = now_us;
        r.u.heartbeat_reply.status = voxhap_session_status(s);
        send(s, &r);
        return;
    }
    if (!s->session_open) {
        if (m->type == VOXHAP_SET_FORCE) {
            s->stats.forces_ignored++; /* arrives at the servo rate: counted, not answered */
        } else {
            reject(s, m->type, VOXHAP_REJECT_NO_SESSION);
        }
        return;
    }
    switch (m->type) {
    case VOXHAP_ENABLE: enable(s, m->u.enable_watchdog_timeout_us, now_us); break;
    case VOXHAP_DISABLE: go_idle(s); break;
    case VOXHAP_SET_FORCE: set_force(s, m, now_us); break;
    case VOXHAP_CLEAR_FAULT:
        if (s->drive == VOXHAP_FAULTED) {
            s->faults = 0;
            s->drive = VOXHAP_IDLE;
        }
        break;
    case VOXHAP_SET_STATE_RATE:
        if (m->u.set_state_rate_hz == 0 || rate_supported(s, m->u.set_state_rate_hz)) {
            s->state_rate_hz = m->u.set_state_rate_hz;
            s->next_state_us = now_us;
        } else {
            reject(s, VOXHAP_SET_STATE_RATE, VOXHAP_REJECT_INVALID_ARGUMENT);
        }
        break;
    default: break;
    }
}

void voxhap_session_raise_fault(voxhap_session *s, uint8_t code, uint64_t now_us) {
    voxhap_device_msg m;
    if (code > VOXHAP_FAULT_MAX) {
        code = VOXHAP_FAULT_INTERNAL;
    }
    if (code != VOXHAP_FAULT_WATCHDOG_EXPIRED) {
        s->faults = (uint16_t)(s->faults | (1u << code));
        s->drive = VOXHAP_FAULTED;
        zero3(s->force_n);
    } else {
        s->watchdog_tripped = 1;
        go_idle(s);
    }
    memset(&m, 0, sizeof m);
    m.type = VOXHAP_FAULT;
    m.u.fault.code = code;
    m.u.fault.active_faults = s->faults;
    m.u.fault.device_time_us = now_us;
    send(s, &m);
}

/* True if a State goes out this cycle; advances the streaming schedule without catch-up bursts. */
static int state_due(voxhap_session *s, uint64_t now_us) {
    int due = s->state_requested;
    s->state_requested = 0;
    if (s->state_rate_hz != 0 && now_us >= s->next_state_us) {
        uint64_t period_us = 1000000u / s->state_rate_hz;
        if (now_us - s->next_state_us >= period_us) {
            s->next_state_us = now_us + period_us; /* fell behind: skip, never burst */
        } else {
            s->next_state_us += period_us;
        }
        due = 1;
    }
    return due;
}

void voxhap_session_poll(voxhap_session *s, uint64_t now_us, const voxhap_sample *sample, float force_out[3]) {
    int finite = 1, i;
    if (s->drive == VOXHAP_ENABLED && now_us > s->last_force_us &&
        now_us - s->last_force_us > s->watchdog_timeout_us) {
        s->stats.watchdog_trips++;
        voxhap_session_raise_fault(s, VOXHAP_FAULT_WATCHDOG_EXPIRED, now_us);
    }
    for (i = 0; i < 3; i++) {
        finite &= voxhap_isfinite(sample->position_m[i]) & voxhap_isfinite(sample->velocity_m_per_s[i]);
    }
    if (!finite) {
        if (!(s->faults & (1u << VOXHAP_FAULT_ENCODER))) {
            voxhap_session_raise_fault(s, VOXHAP_FAULT_ENCODER, now_us);
        }
        /* No State carries a non-finite number; a pending lockstep State waits for a finite sample. */
    } else if (s->session_open && state_due(s, now_us)) {
        voxhap_device_msg m;
        memset(&m, 0, sizeof m);
        m.type = VOXHAP_STATE;
        s->state_sequence++;
        m.u.state.sequence = s->state_sequence;
        m.u.state.device_time_us = now_us;
        memcpy(m.u.state.position_m, sample->position_m, sizeof m.u.state.position_m);
        memcpy(m.u.state.velocity_m_per_s, sample->velocity_m_per_s, sizeof m.u.state.velocity_m_per_s);
        m.u.state.last_force_sequence = s->last_force_sequence;
        m.u.state.buttons = sample->buttons;
        m.u.state.status = voxhap_session_status(s);
        m.u.state.faults = s->faults;
        s->stats.states_queued++;
        send(s, &m);
    }
    if (s->drive == VOXHAP_ENABLED) {
        memcpy(force_out, s->force_n, 3 * sizeof(float));
    } else {
        zero3(force_out);
    }
}

int voxhap_session_poll_transmit(voxhap_session *s, voxhap_device_msg *out) {
    if (s->outbox_len == 0) {
        return 0;
    }
    *out = s->outbox[s->outbox_head];
    s->outbox_head = (uint8_t)((s->outbox_head + 1u) % VOXHAP_OUTBOX_CAPACITY);
    s->outbox_len--;
    return 1;
}

static float fabs_f(float x) { return x < 0.0f ? -x : x; }

int voxhap_clamp_magnitude(const float f[3], float max_n, float out[3]) {
    float m = fabs_f(f[0]), g0, g1, g2, n;
    if (fabs_f(f[1]) > m) m = fabs_f(f[1]);
    if (fabs_f(f[2]) > m) m = fabs_f(f[2]);
    if (!(max_n > 0.0f) || !voxhap_isfinite(m)) {
        /* a zero (or negative) limit, or a non-finite input: nothing may be applied */
        zero3(out);
        return m > 0.0f || !voxhap_isfinite(m);
    }
    if (m == 0.0f) {
        zero3(out);
        return 0;
    }
    /* |f| = m * |f / m|, with |f / m| in [1, sqrt 3]: no overflow or underflow in the squares. */
    g0 = f[0] / m;
    g1 = f[1] / m;
    g2 = f[2] / m;
    n = sqrtf(g0 * g0 + g1 * g1 + g2 * g2);
    if (m * n <= max_n) { /* m * n may round to infinity for huge forces: then it clamps, as it must */
        out[0] = f[0];
        out[1] = f[1];
        out[2] = f[2];
        return 0;
    }
    {
        float scale = (max_n / m) / n;
        out[0] = f[0] * scale;
        out[1] = f[1] * scale;
        out[2] = f[2] * scale;
    }
    return 1;
}
