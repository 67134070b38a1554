/* The bare-metal port: the firmware library on an Arm MPS2 board with the AN386 image (Cortex-M4F, 25 MHz), as
 * qemu-system-arm -M mps2-an386 emulates it. Its "hardware" is a simulated 3-DOF arm (ports/common/sim_arm).
 *
 *   UART0 (CMSDK APB UART, 0x40004000): the protocol link to the host (qemu: -serial pty)
 *   UART1 (0x40005000): the event log of ports/common/fwlog.h (qemu: -serial file:LOG)
 *   TIMER0 (CMSDK APB timer, 0x40000000): free-running at the 25 MHz peripheral clock, extended to 64-bit us
 *
 * Interrupts: UART0 RX (IRQ 0) fills a receive ring, TIMER1 (IRQ 9) marks each millisecond; the main loop sleeps
 * (WFI) until either, then runs the firmware: a control cycle after every received message and at least every 1 ms.
 * No heap. Built with VOXHAP_BENCH it instead measures the library's
 * work per control cycle (run under qemu -icount shift=0, where one instruction takes 1 ns of virtual time) and
 * reports it on UART0, then exits through semihosting. */
#include "fwlog.h"
#include "sim_arm.h"
#include "voxhap.h"

#include <string.h>

#define REG(addr) (*(volatile uint32_t *)(addr))

#define UART0 0x40004000u
#define UART1 0x40005000u
#define UART_DATA 0x00u
#define UART_STATE 0x04u /* bit 0 TX full, bit 1 RX full */
#define UART_CTRL 0x08u  /* bit 0 TX enable, bit 1 RX enable */
#define UART_INT 0x0Cu  /* status / clear: bit 0 TX, bit 1 RX */
#define UART_BAUDDIV 0x10u
#define UART_CTRL_RX_IRQ 0x8u

#define TIMER0 0x40000000u
#define TIMER_CTRL 0x00u
#define TIMER_VALUE 0x04u
#define TIMER_RELOAD 0x08u
#define TIMER_INT 0x0Cu
#define TIMER1 0x40001000u
#define NVIC_ISER0 0xE000E100u

#define PCLK_HZ 25000000u

static void uart_init(uint32_t base, uint32_t baud) {
    REG(base + UART_BAUDDIV) = PCLK_HZ / baud; /* 25 at 1 Mbaud; the CMSDK UART needs >= 16 */
    REG(base + UART_CTRL) = 0x3u;
}

static void uart_put(uint32_t base, uint8_t byte) {
    while (REG(base + UART_STATE) & 0x1u) {
    }
    REG(base + UART_DATA) = byte;
}

/* ------------------------------------------------------------------------------------------------ clock */

static uint64_t ticks_total;
static uint32_t ticks_last;

static void timer_init(void) {
    REG(TIMER0 + TIMER_CTRL) = 0;
    REG(TIMER0 + TIMER_RELOAD) = 0xFFFFFFFFu;
    REG(TIMER0 + TIMER_VALUE) = 0xFFFFFFFFu;
    REG(TIMER0 + TIMER_CTRL) = 0x1u; /* enable, no interrupt */
    ticks_last = REG(TIMER0 + TIMER_VALUE);
}

/* A down-counter that wraps every 171 s; called at least every millisecond, so no wrap is ever missed. */
static uint64_t ticks_now(void) {
    uint32_t v = REG(TIMER0 + TIMER_VALUE);
    ticks_total += (uint32_t)(ticks_last - v);
    ticks_last = v;
    return ticks_total;
}

static uint64_t now_us(void *ctx) {
    (void)ctx;
    return ticks_now() / (PCLK_HZ / 1000000u);
}

/* ------------------------------------------------------------------------------------------------ HAL */

typedef struct {
    sim_arm arm;
    uint64_t last_sample_us;
    fwlog log;
} board;

/* Receive ring: written by the UART0 RX interrupt, read by the main loop (single producer, single consumer). */
static volatile uint8_t rx_ring[256];
static volatile uint32_t rx_head, rx_tail, rx_overruns;
static volatile uint32_t ms_ticks;

void UART0RX_Handler(void);
void TIMER1_Handler(void);

void UART0RX_Handler(void) {
    REG(UART0 + UART_INT) = 0x2u;
    while (REG(UART0 + UART_STATE) & 0x2u) {
        uint8_t byte = (uint8_t)REG(UART0 + UART_DATA);
        if (rx_head - rx_tail < sizeof rx_ring) {
            rx_ring[rx_head % sizeof rx_ring] = byte;
            rx_head++;
        } else {
            rx_overruns++; /* the decoder resynchronises at the next 0x00 */
        }
    }
}

void TIMER1_Handler(void) {
    REG(TIMER1 + TIMER_INT) = 0x1u;
    ms_ticks++;
}

static size_t uart_read(void *ctx, uint8_t *buf, size_t cap) {
    size_t n = 0;
    (void)ctx;
    while (n < cap && rx_tail != rx_head) {
        buf[n++] = rx_ring[rx_tail % sizeof rx_ring];
        rx_tail++;
    }
    return n;
}

static void uart_write(void *ctx, const uint8_t *buf, size_t len) {
    (void)ctx;
    while (len--) {
        uart_put(UART0, *buf++);
    }
}

static void read_sample(void *ctx, voxhap_sample *s) {
    board *b = ctx;
    uint64_t t = now_us(ctx);
    sim_arm_step(&b->arm, (float)(uint32_t)(t - b->last_sample_us) * 1e-6f);
    b->last_sample_us = t;
    memcpy(s->position_m, b->arm.position_m, sizeof s->position_m);
    memcpy(s->velocity_m_per_s, b->arm.velocity_m_per_s, sizeof s->velocity_m_per_s);
    s->buttons = 0;
}

static void write_force(void *ctx, const float f[3]) {
    board *b = ctx;
    /* A real arm: joint torques = J(q)^T f, then a current per motor (torque / torque constant). */
    memcpy(b->arm.force_n, f, sizeof b->arm.force_n);
}

static void on_message(void *ctx, const voxhap_host_msg *m, uint64_t t) { fwlog_message(&((board *)ctx)->log, m, t); }
static void on_reply(void *ctx, const voxhap_device_msg *m, uint64_t t) { fwlog_reply(&((board *)ctx)->log, m, t); }

/* Log lines are kept in RAM during a cycle and written to UART1 after the cycle's replies went out on UART0, so
 * that logging never delays a State. A cycle writes a few lines; a full buffer drops the rest of the line. */
static char log_buf[2048];
static uint32_t log_len;

static void log_write(void *ctx, const char *text, uint32_t len) {
    (void)ctx;
    if (log_len + len <= sizeof log_buf) {
        memcpy(log_buf + log_len, text, len);
        log_len += len;
    }
}

static void log_flush(void) {
    uint32_t i;
    for (i = 0; i < log_len; i++) {
        uart_put(UART1, (uint8_t)log_buf[i]);
    }
    log_len = 0;
}

static voxhap_device_info device_info(void) {
    voxhap_device_info info;
    int i;
    memset(&info, 0, sizeof info);
    info.version.major = VOXHAP_VERSION_MAJOR;
    info.version.minor = VOXHAP_VERSION_MINOR;
    memcpy(info.model, "voxhap-c-m4", 11);
    memcpy(info.serial_number, "QEMU-AN386", 10);
    info.position_dof = 3;
    info.force_dof = 3;
    info.supported_rates = VOXHAP_RATE_500 | VOXHAP_RATE_1000;
    for (i = 0; i < 3; i++) {
        info.workspace_min_m[i] = -0.1f;
        info.workspace_max_m[i] = 0.1f;
    }
    info.max_force_n = 5.0f;
    info.max_stiffness_n_per_m = 2000.0f;
    return info;
}

static board the_board;
static voxhap_fw fw;

static voxhap_hal board_hal(void) {
    voxhap_hal hal;
    memset(&hal, 0, sizeof hal);
    hal.ctx = &the_board;
    hal.now_us = now_us;
    hal.uart_read = uart_read;
    hal.uart_write = uart_write;
    hal.read_sample = read_sample;
    hal.write_force = write_force;
    hal.on_message = on_message;
    hal.on_reply = on_reply;
    return hal;
}

#ifndef VOXHAP_BENCH

static void interrupts_init(void) {
    REG(UART0 + UART_CTRL) |= UART_CTRL_RX_IRQ;
    REG(TIMER1 + TIMER_CTRL) = 0;
    REG(TIMER1 + TIMER_RELOAD) = PCLK_HZ / 1000u - 1u; /* 1 kHz */
    REG(TIMER1 + TIMER_VALUE) = PCLK_HZ / 1000u - 1u;
    REG(TIMER1 + TIMER_CTRL) = 0x9u; /* enable, interrupt enable */
    REG(NVIC_ISER0) = (1u << 0) | (1u << 9);
}

int main(void) {
    voxhap_hal hal = board_hal();
    voxhap_device_info info = device_info();
    uint32_t last_ms = 0;
    int zero_logged = 0;
    uart_init(UART0, 1000000u);
    uart_init(UART1, 1000000u);
    timer_init();
    the_board.log.write = log_write;
    sim_arm_init(&the_board.arm);
    if (voxhap_fw_init(&fw, &hal, &info, 1000.0f) != VOXHAP_OK) {
        fwlog_event(&the_board.log, 'X', "bad_info", 0, 0);
        log_flush();
        for (;;) {
        }
    }
    fwlog_event(&the_board.log, 'X', "reset", 5, now_us(0));
    log_flush();
    voxhap_fw_start(&fw);
    interrupts_init();
    for (;;) {
        uint32_t handled, ms;
        /* Sleep until a byte or a millisecond tick: check with interrupts masked, so that one arriving between
         * the check and WFI still wakes it (a pending interrupt ends WFI even while masked). */
        __asm volatile("cpsid i" ::: "memory");
        if (rx_tail == rx_head && ms_ticks == last_ms) {
            __asm volatile("wfi" ::: "memory");
        }
        __asm volatile("cpsie i" ::: "memory");
        handled = voxhap_fw_receive(&fw);
        ms = ms_ticks;
        /* A control cycle after each message (the State goes out at once) and on every millisecond tick. */
        if (handled > 0 || ms != last_ms) {
            last_ms = ms;
            voxhap_fw_control(&fw);
            /* Log every non-zero force, and the first zero of a run (a zero held is not repeated). */
            if (fw.applied_n[0] != 0.0f || fw.applied_n[1] != 0.0f || fw.applied_n[2] != 0.0f || !zero_logged) {
                fwlog_applied(&the_board.log, fw.applied_n, fw.last_control_us);
            }
            zero_logged = fw.applied_n[0] == 0.0f && fw.applied_n[1] == 0.0f && fw.applied_n[2] == 0.0f;
        }
        log_flush();
    }
}

#else /* VOXHAP_BENCH */

/* The bench HAL: bytes come from a buffer of pre-encoded frames, replies go nowhere, the sample is fixed. */
static const uint8_t *bench_rx;
static size_t bench_rx_len;
static size_t bench_tx_bytes;

static size_t bench_read(void *ctx, uint8_t *buf, size_t cap) {
    size_t n = bench_rx_len < cap ? bench_rx_len : cap;
    (void)ctx;
    memcpy(buf, bench_rx, n);
    bench_rx += n;
    bench_rx_len -= n;
    return n;
}
static void bench_write(void *ctx, const uint8_t *buf, size_t len) {
    (void)ctx;
    (void)buf;
    bench_tx_bytes += len;
}
static void bench_sample(void *ctx, voxhap_sample *s) {
    (void)ctx;
    s->position_m[0] = 0.01f;
    s->position_m[1] = -0.02f;
    s->position_m[2] = 0.03f;
    s->velocity_m_per_s[0] = 0.1f;
}
static void bench_force(void *ctx, const float f[3]) {
    (void)ctx;
    (void)f;
}

static void put_str(const char *s) {
    while (*s) uart_put(UART0, (uint8_t)*s++);
}
static void put_num(uint32_t v) {
    char d[10];
    int n = 0;
    do {
        d[n++] = (char)('0' + (int)(v % 10u));
        v /= 10u;
    } while (v && n < 10);
    while (n) uart_put(UART0, (uint8_t)d[--n]);
}

static void semihosting_exit(void) {
    /* SYS_EXIT (0x18) with ADP_Stopped_ApplicationExit */
    register uint32_t op __asm__("r0") = 0x18u;
    register uint32_t arg __asm__("r1") = 0x20026u;
    __asm volatile("bkpt 0xAB" : : "r"(op), "r"(arg) : "memory");
}

#define BENCH_CYCLES 2000u

/* Instructions per control cycle of the library alone: receive one SetForce frame (decode, session), control
 * (watchdog, State, clamp, slew), encode and write the State. Under -icount shift=0 one instruction is 1 ns, and the
 * 25 MHz timer ticks every 40 ns, so instructions = ticks * 40. */
int main(void) {
    static uint8_t frames[BENCH_CYCLES][VOXHAP_MAX_WIRE_FRAME_LEN];
    static size_t lens[BENCH_CYCLES];
    voxhap_hal hal;
    voxhap_device_info info = device_info();
    voxhap_host_msg m;
    uint8_t hello[16], enable[16];
    size_t hello_len, enable_len;
    uint32_t i;
    uint64_t t0, t1, e0, e1;
    uart_init(UART0, 1000000u);
    timer_init();
    hal = board_hal(); /* the board's clock; the rest replaced, and no logging */
    hal.on_message = NULL;
    hal.on_reply = NULL;
    the_board.log.write = log_write;
    log_flush();
    hal.uart_read = bench_read;
    hal.uart_write = bench_write;
    hal.read_sample = bench_sample;
    hal.write_force = bench_force;
    voxhap_fw_init(&fw, &hal, &info, 1000.0f);
    memset(&m, 0, sizeof m);
    m.type = VOXHAP_HELLO;
    m.u.hello.major = 1;
    hello_len = voxhap_encode_host(&m, hello, sizeof hello);
    m.type = VOXHAP_ENABLE;
    m.u.enable_watchdog_timeout_us = 1000000u;
    enable_len = voxhap_encode_host(&m, enable, sizeof enable);
    for (i = 0; i < BENCH_CYCLES; i++) {
        memset(&m, 0, sizeof m);
        m.type = VOXHAP_SET_FORCE;
        m.u.set_force.sequence = i + 1u;
        m.u.set_force.force_n[0] = 0.5f + 0.001f * (float)(i % 100u);
        m.u.set_force.force_n[1] = -1.25f;
        m.u.set_force.force_n[2] = 2.0f;
        lens[i] = voxhap_encode_host(&m, frames[i], sizeof frames[i]);
    }
    bench_rx = hello;
    bench_rx_len = hello_len;
    voxhap_fw_tick(&fw);
    bench_rx = enable;
    bench_rx_len = enable_len;
    voxhap_fw_tick(&fw);
    /* An empty loop of the same shape, to subtract the timer reads and loop overhead. */
    e0 = ticks_now();
    for (i = 0; i < BENCH_CYCLES; i++) {
        bench_rx = frames[i];
        bench_rx_len = 0;
        __asm volatile("" ::: "memory");
    }
    e1 = ticks_now();
    bench_tx_bytes = 0;
    t0 = ticks_now();
    for (i = 0; i < BENCH_CYCLES; i++) {
        bench_rx = frames[i];
        bench_rx_len = lens[i];
        voxhap_fw_tick(&fw);
    }
    t1 = ticks_now();
    put_str("bench: ");
    put_num(BENCH_CYCLES);
    put_str(" control cycles (SetForce in, State out): ");
    put_num((uint32_t)(((t1 - t0) - (e1 - e0)) * 40u / BENCH_CYCLES));
    put_str(" instructions per cycle (an empty loop iteration measures ");
    put_num((uint32_t)((e1 - e0) * 40u / BENCH_CYCLES));
    put_str("); state bytes out ");
    put_num((uint32_t)bench_tx_bytes);
    put_str("; frames ok ");
    put_num(fw.decoder.stats.frames_ok);
    put_str("; enabled ");
    put_num(fw.session.drive == VOXHAP_ENABLED);
    put_str("\n");
    semihosting_exit();
    for (;;) {
    }
}

#endif
