#include "fwlog.h"

#include <string.h>

static void put_c(fwlog *l, char c) {
    if (l->len < sizeof l->line) {
        l->line[l->len++] = c;
    }
}

static void put_s(fwlog *l, const char *s) {
    while (*s) {
        put_c(l, *s++);
    }
}

static void put_u64(fwlog *l, uint64_t v) {
    char digits[20];
    int n = 0;
    put_c(l, ' ');
    do {
        digits[n++] = (char)('0' + (int)(v % 10u));
        v /= 10u;
    } while (v != 0 && n < 20);
    while (n > 0) {
        put_c(l, digits[--n]);
    }
}

static void put_hex(fwlog *l, uint32_t v, int digits) {
    static const char hex[] = "0123456789abcdef";
    put_c(l, ' ');
    while (digits-- > 0) {
        put_c(l, hex[(v >> (4 * digits)) & 0xFu]);
    }
}

static void put_f32(fwlog *l, float f) {
    uint32_t u;
    memcpy(&u, &f, sizeof u);
    put_hex(l, u, 8);
}

static void begin(fwlog *l, char kind, uint64_t now_us) {
    l->len = 0;
    put_c(l, kind);
    put_u64(l, now_us);
}

static void end(fwlog *l) {
    put_c(l, '\n');
    l->write(l->ctx, l->line, l->len);
}

void fwlog_message(fwlog *l, const voxhap_host_msg *m, uint64_t now_us) {
    if (m->type == VOXHAP_SET_FORCE) {
        begin(l, 'S', now_us);
        put_u64(l, m->u.set_force.sequence);
        put_f32(l, m->u.set_force.force_n[0]);
        put_f32(l, m->u.set_force.force_n[1]);
        put_f32(l, m->u.set_force.force_n[2]);
        put_u64(l, m->u.set_force.flags);
        end(l);
        return;
    }
    begin(l, 'M', now_us);
    put_hex(l, m->type, 2);
    switch (m->type) {
    case VOXHAP_HELLO: put_u64(l, (uint64_t)m->u.hello.major * 256u + m->u.hello.minor); break;
    case VOXHAP_ENABLE: put_u64(l, m->u.enable_watchdog_timeout_us); break;
    case VOXHAP_HEARTBEAT: put_u64(l, m->u.heartbeat_counter); break;
    case VOXHAP_SET_STATE_RATE: put_u64(l, m->u.set_state_rate_hz); break;
    default: put_u64(l, 0); break;
    }
    end(l);
}

void fwlog_reply(fwlog *l, const voxhap_device_msg *m, uint64_t now_us) {
    uint32_t a = 0, b = 0;
    switch (m->type) {
    case VOXHAP_STATE: return; /* one per SetForce: the S line stands for it */
    case VOXHAP_FAULT:
        a = m->u.fault.code;
        b = m->u.fault.active_faults;
        break;
    case VOXHAP_REJECTED:
        a = m->u.rejected.message_type;
        b = m->u.rejected.reason;
        break;
    case VOXHAP_HEARTBEAT_REPLY:
        a = m->u.heartbeat_reply.counter;
        b = m->u.heartbeat_reply.status;
        break;
    default: break;
    }
    begin(l, 'T', now_us);
    put_hex(l, m->type, 2);
    put_u64(l, a);
    put_u64(l, b);
    end(l);
}

void fwlog_applied(fwlog *l, const float f[3], uint64_t now_us) {
    begin(l, 'A', now_us);
    put_f32(l, f[0]);
    put_f32(l, f[1]);
    put_f32(l, f[2]);
    end(l);
}

void fwlog_event(fwlog *l, char kind, const char *event, uint32_t arg, uint64_t now_us) {
    begin(l, kind, now_us);
    put_c(l, ' ');
    put_s(l, event);
    put_u64(l, arg);
    end(l);
}
