/* The firmware loop around the session: HAL calls, hardware faults, slew limit, framing of replies. */
#include "voxhap.h"

#include <math.h>
#include <string.h>

static float norm3(const float v[3]) { return sqrtf(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]); }

void voxhap_slew_limit(const float prev[3], const float f[3], float max_rise_n, float out[3]) {
    float p = norm3(prev), n = norm3(f), allowed = p + max_rise_n;
    if (n <= allowed) {
        out[0] = f[0];
        out[1] = f[1];
        out[2] = f[2];
    } else {
        float scale = allowed / n;
        out[0] = f[0] * scale;
        out[1] = f[1] * scale;
        out[2] = f[2] * scale;
    }
}

voxhap_result voxhap_fw_init(voxhap_fw *fw, const voxhap_hal *hal, const voxhap_device_info *info,
                             float max_rise_n_per_s) {
    memset(fw, 0, sizeof *fw);
    fw->hal = *hal;
    fw->max_rise_n_per_s = max_rise_n_per_s > 0.0f && voxhap_isfinite(max_rise_n_per_s) ? max_rise_n_per_s : 0.0f;
    voxhap_decoder_init(&fw->decoder);
    return voxhap_session_init(&fw->session, info);
}

void voxhap_fw_start(voxhap_fw *fw) {
    static const uint8_t delimiter = 0x00;
    float zero[3] = {0.0f, 0.0f, 0.0f};
    fw->hal.write_force(fw->hal.ctx, zero);
    fw->hal.uart_write(fw->hal.ctx, &delimiter, 1); /* SPEC 4.3: a lone 0x00 before any other byte */
    fw->last_control_us = fw->hal.now_us(fw->hal.ctx);
}

uint32_t voxhap_fw_receive(voxhap_fw *fw) {
    uint8_t chunk[32];
    uint32_t handled = 0;
    size_t n, i;
    /* Bounded: at most 8 chunks (256 bytes, about 11 SetForce frames) per call, so a flooded link cannot starve
     * the control cycle; the rest waits in the UART's buffer for the next call. */
    int rounds = 8;
    while (rounds-- > 0 && (n = fw->hal.uart_read(fw->hal.ctx, chunk, sizeof chunk)) > 0) {
        uint64_t now = fw->hal.now_us(fw->hal.ctx);
        for (i = 0; i < n; i++) {
            voxhap_host_msg m;
            if (voxhap_decoder_push_host(&fw->decoder, chunk[i], &m) == VOXHAP_OK) {
                if (fw->hal.on_message) {
                    fw->hal.on_message(fw->hal.ctx, &m, now);
                }
                voxhap_session_on_message(&fw->session, &m, now);
                handled++;
            }
        }
    }
    fw->messages += handled;
    return handled;
}

void voxhap_fw_control(voxhap_fw *fw) {
    voxhap_sample sample;
    voxhap_device_msg reply;
    float commanded[3], out[3];
    uint64_t now = fw->hal.now_us(fw->hal.ctx);
    uint64_t dt_us = now - fw->last_control_us;
    fw->last_control_us = now;

    if (fw->hal.read_faults) {
        /* Raise each hardware fault once per appearance (it latches; ClearFault lets it be raised again). */
        uint16_t present = (uint16_t)(fw->hal.read_faults(fw->hal.ctx) & 0xFFFEu);
        uint16_t fresh = (uint16_t)(present & ~fw->session.faults);
        uint8_t code;
        for (code = 1; code <= VOXHAP_FAULT_MAX; code++) {
            if (fresh & (1u << code)) {
                voxhap_session_raise_fault(&fw->session, code, now);
            }
        }
        fw->hw_faults_seen |= present;
    }
    memset(&sample, 0, sizeof sample);
    fw->hal.read_sample(fw->hal.ctx, &sample);
    voxhap_session_poll(&fw->session, now, &sample, commanded);

    if (fw->max_rise_n_per_s > 0.0f) {
        /* dt capped at 10 ms: after a long gap the rise allowed is still a small step */
        float dt_s = (float)(dt_us > 10000u ? 10000u : dt_us) * 1e-6f;
        voxhap_slew_limit(fw->applied_n, commanded, fw->max_rise_n_per_s * dt_s, out);
    } else {
        memcpy(out, commanded, sizeof out);
    }
    fw->hal.write_force(fw->hal.ctx, out);
    memcpy(fw->applied_n, out, sizeof out);

    while (voxhap_session_poll_transmit(&fw->session, &reply)) {
        uint8_t frame[VOXHAP_MAX_WIRE_FRAME_LEN + 1];
        size_t len, at = 0;
        if (reply.type == VOXHAP_DEVICE_INFO) {
            frame[at++] = 0x00; /* SPEC 4.3: a delimiter before each DeviceInfo */
        }
        if (fw->hal.on_reply) {
            fw->hal.on_reply(fw->hal.ctx, &reply, now);
        }
        len = voxhap_encode_device(&reply, frame + at, sizeof frame - at);
        if (len > 0) {
            fw->hal.uart_write(fw->hal.ctx, frame, at + len);
        }
    }
}

void voxhap_fw_tick(voxhap_fw *fw) {
    voxhap_fw_receive(fw);
    voxhap_fw_control(fw);
}
