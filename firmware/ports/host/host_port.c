/* The host port: the firmware library in a POSIX process, behind a pseudo-terminal, with a simulated 3-DOF arm as
 * its hardware. `voxhap serve --device serial:LINK` talks to it exactly as to a board on a USB-serial port; the
 * port logs everything it receives and applies (ports/common/fwlog.h) for firmware/tools/check_log.py.
 *
 *   voxhap-fw-host --link PATH --log FILE [--duration S] [--max-force N] [--garbage-ms MS] [--seed N]
 *
 * Signals: SIGUSR1 resets the "board" (closes the pseudo-terminal, restarts the firmware, opens a new one and
 * re-points PATH: the host sees a hang-up and reconnects); SIGUSR2 raises a persistent over-temperature fault;
 * SIGINT/SIGTERM end it. --garbage-ms injects a burst of random bytes ending in 0x00 every MS milliseconds into
 * both directions, always between frames (so no real frame is lost, and every burst must be dropped). */
#include "fwlog.h"
#include "sim_arm.h"
#include "voxhap.h"

#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

typedef struct {
    int master, slave;
    char pts[128];
    const char *link;
    FILE *log_file;
    fwlog log;
    sim_arm arm;
    uint64_t last_sample_us;
    uint16_t faults_present;
    uint32_t tx_dropped;
    voxhap_fw fw;
} port;

static volatile sig_atomic_t stop_requested = 0, reset_requested = 0, fault_requested = 0;

static void on_signal(int sig) {
    if (sig == SIGUSR1) reset_requested = 1;
    else if (sig == SIGUSR2) fault_requested = 1;
    else stop_requested = 1;
}

static struct timespec start_time;

static uint64_t now_us(void *ctx) {
    struct timespec t;
    (void)ctx;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (uint64_t)(t.tv_sec - start_time.tv_sec) * 1000000u + (uint64_t)(t.tv_nsec / 1000) -
           (uint64_t)(start_time.tv_nsec / 1000);
}

static size_t uart_read(void *ctx, uint8_t *buf, size_t cap) {
    port *p = ctx;
    ssize_t n = read(p->master, buf, cap);
    return n > 0 ? (size_t)n : 0;
}

static void uart_write(void *ctx, const uint8_t *buf, size_t len) {
    port *p = ctx;
    while (len > 0) {
        ssize_t n = write(p->master, buf, len);
        if (n <= 0) {
            p->tx_dropped += (uint32_t)len; /* nobody reading (buffer full): dropped; the next 0x00 resyncs */
            return;
        }
        buf += n;
        len -= (size_t)n;
    }
}

static void read_sample(void *ctx, voxhap_sample *s) {
    port *p = ctx;
    uint64_t t = now_us(ctx);
    sim_arm_step(&p->arm, (float)(t - p->last_sample_us) * 1e-6f);
    p->last_sample_us = t;
    memcpy(s->position_m, p->arm.position_m, sizeof s->position_m);
    memcpy(s->velocity_m_per_s, p->arm.velocity_m_per_s, sizeof s->velocity_m_per_s);
    s->buttons = 0;
}

static void write_force(void *ctx, const float f[3]) {
    port *p = ctx;
    memcpy(p->arm.force_n, f, sizeof p->arm.force_n);
}

static uint16_t read_faults(void *ctx) { return ((port *)ctx)->faults_present; }

static void on_message(void *ctx, const voxhap_host_msg *m, uint64_t t) { fwlog_message(&((port *)ctx)->log, m, t); }

static void on_reply(void *ctx, const voxhap_device_msg *m, uint64_t t) { fwlog_reply(&((port *)ctx)->log, m, t); }

static void log_write(void *ctx, const char *text, uint32_t len) { fwrite(text, 1, len, (FILE *)ctx); }

static int open_pty(port *p) {
    struct termios tio;
    const char *name;
    p->master = posix_openpt(O_RDWR | O_NOCTTY);
    if (p->master < 0 || grantpt(p->master) != 0 || unlockpt(p->master) != 0 || !(name = ptsname(p->master))) {
        perror("voxhap-fw-host: posix_openpt");
        return -1;
    }
    snprintf(p->pts, sizeof p->pts, "%s", name);
    /* Keep the slave open ourselves: the master then never reads EIO while no host has the port open, and the
     * line is raw from the start (the host sets raw mode too when it opens it). */
    p->slave = open(p->pts, O_RDWR | O_NOCTTY);
    if (p->slave < 0 || tcgetattr(p->slave, &tio) != 0) {
        perror("voxhap-fw-host: opening the pseudo-terminal");
        return -1;
    }
    cfmakeraw(&tio);
    tcsetattr(p->slave, TCSANOW, &tio);
    fcntl(p->master, F_SETFL, fcntl(p->master, F_GETFL) | O_NONBLOCK);
    if (p->link) {
        struct stat st;
        if (lstat(p->link, &st) == 0) {
            if (!S_ISLNK(st.st_mode)) {
                fprintf(stderr, "voxhap-fw-host: %s exists and is not a symbolic link; not replacing it\n", p->link);
                return -1;
            }
            unlink(p->link);
        }
        if (symlink(p->pts, p->link) != 0) {
            fprintf(stderr, "voxhap-fw-host: cannot link %s to %s: %s\n", p->link, p->pts, strerror(errno));
            return -1;
        }
    }
    printf("serving %s\n", p->pts);
    fflush(stdout);
    return 0;
}

static void close_pty(port *p) {
    close(p->master);
    close(p->slave);
}

static voxhap_device_info device_info(float max_force_n) {
    voxhap_device_info info;
    int i;
    memset(&info, 0, sizeof info);
    info.version.major = VOXHAP_VERSION_MAJOR;
    info.version.minor = VOXHAP_VERSION_MINOR;
    memcpy(info.model, "voxhap-c-pty", 12);
    memcpy(info.serial_number, "HOST-0001", 9);
    info.position_dof = 3;
    info.force_dof = 3;
    info.button_count = 0;
    info.supported_rates = VOXHAP_RATE_500 | VOXHAP_RATE_1000;
    for (i = 0; i < 3; i++) {
        info.workspace_min_m[i] = -0.1f;
        info.workspace_max_m[i] = 0.1f;
    }
    info.max_force_n = max_force_n;
    info.max_stiffness_n_per_m = 2000.0f;
    return info;
}

/* Firmware rise limit: 1 N per ms, twice the host's own slew limit, so it only acts if the host misbehaves. */
#define MAX_RISE_N_PER_S 1000.0f

static int start_firmware(port *p, float max_force_n) {
    voxhap_hal hal;
    voxhap_device_info info = device_info(max_force_n);
    memset(&hal, 0, sizeof hal);
    hal.ctx = p;
    hal.now_us = now_us;
    hal.uart_read = uart_read;
    hal.uart_write = uart_write;
    hal.read_sample = read_sample;
    hal.write_force = write_force;
    hal.read_faults = read_faults;
    hal.on_message = on_message;
    hal.on_reply = on_reply;
    sim_arm_init(&p->arm);
    p->last_sample_us = now_us(p);
    if (voxhap_fw_init(&p->fw, &hal, &info, MAX_RISE_N_PER_S) != VOXHAP_OK) {
        fprintf(stderr, "voxhap-fw-host: invalid device info (max force %g N?)\n", (double)max_force_n);
        return -1;
    }
    fwlog_event(&p->log, 'X', "reset", (uint32_t)max_force_n, now_us(p));
    voxhap_fw_start(&p->fw);
    return 0;
}

static uint32_t rng_state = 1;
static uint32_t rng(void) {
    rng_state ^= rng_state << 13;
    rng_state ^= rng_state >> 17;
    rng_state ^= rng_state << 5;
    return rng_state;
}

/* 1..12 random non-zero bytes, then 0x00: one frame the receiver must drop. */
static size_t garbage(uint8_t *buf) {
    size_t n = 1 + rng() % 12, i;
    for (i = 0; i < n; i++) buf[i] = (uint8_t)(1 + rng() % 255);
    buf[n] = 0;
    return n + 1;
}

static double arg_num(const char *flag, const char *v, double lo, double hi) {
    char *end;
    double x = v ? strtod(v, &end) : 0.0;
    if (!v || *end != 0 || !(x >= lo && x <= hi)) {
        fprintf(stderr, "voxhap-fw-host: %s needs a number in %g..%g, got %s\n", flag, lo, hi, v ? v : "nothing");
        exit(2);
    }
    return x;
}

int main(int argc, char **argv) {
    static port p;
    const char *log_path = NULL;
    double duration_s = 0, max_force_n = 5.0, garbage_ms = 0;
    uint64_t next_control, next_garbage, next_flush, end_us;
    struct sigaction sa;
    int i;
    for (i = 1; i < argc; i++) {
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (!strcmp(argv[i], "--link")) p.link = v, i++;
        else if (!strcmp(argv[i], "--log")) log_path = v, i++;
        else if (!strcmp(argv[i], "--duration")) duration_s = arg_num(argv[i], v, 0, 1e6), i++;
        else if (!strcmp(argv[i], "--max-force")) max_force_n = arg_num(argv[i], v, 0, 1000), i++;
        else if (!strcmp(argv[i], "--garbage-ms")) garbage_ms = arg_num(argv[i], v, 0, 1e6), i++;
        else if (!strcmp(argv[i], "--seed")) rng_state = (uint32_t)arg_num(argv[i], v, 1, 4294967295.0), i++;
        else {
            fprintf(stderr, "usage: voxhap-fw-host --log FILE [--link PATH] [--duration S] [--max-force N] "
                            "[--garbage-ms MS] [--seed N]\n(unknown argument %s)\n", argv[i]);
            return 2;
        }
    }
    if (!log_path) {
        fprintf(stderr, "voxhap-fw-host: --log FILE is required\n");
        return 2;
    }
    p.log_file = fopen(log_path, "w");
    if (!p.log_file) {
        fprintf(stderr, "voxhap-fw-host: cannot create %s: %s\n", log_path, strerror(errno));
        return 1;
    }
    setvbuf(p.log_file, NULL, _IOFBF, 1 << 16);
    p.log.write = log_write;
    p.log.ctx = p.log_file;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGUSR1, &sa, NULL);
    sigaction(SIGUSR2, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);
    clock_gettime(CLOCK_MONOTONIC, &start_time);
    if (open_pty(&p) != 0 || start_firmware(&p, (float)max_force_n) != 0) {
        return 1;
    }
    next_control = now_us(&p) + 1000;
    next_garbage = now_us(&p) + (uint64_t)(garbage_ms * 1000);
    next_flush = now_us(&p);
    end_us = duration_s > 0 ? (uint64_t)(duration_s * 1e6) : UINT64_MAX;

    while (!stop_requested) {
        uint64_t t = now_us(&p);
        struct pollfd pfd;
        struct timespec wait;
        uint64_t wait_us;
        if (t >= end_us) break;
        if (reset_requested) {
            reset_requested = 0;
            close_pty(&p);
            if (open_pty(&p) != 0 || start_firmware(&p, (float)max_force_n) != 0) return 1;
        }
        if (fault_requested) {
            fault_requested = 0;
            p.faults_present |= 1u << VOXHAP_FAULT_OVER_TEMPERATURE;
            fwlog_event(&p.log, 'X', "fault", VOXHAP_FAULT_OVER_TEMPERATURE, t);
        }
        wait_us = next_control > t ? next_control - t : 0;
        pfd.fd = p.master;
        pfd.events = POLLIN;
        wait.tv_sec = 0;
        wait.tv_nsec = (long)wait_us * 1000;
        ppoll(&pfd, 1, &wait, NULL);
        t = now_us(&p);
        if (garbage_ms > 0 && t >= next_garbage && p.fw.decoder.len == 0 && !p.fw.decoder.overflow) {
            uint8_t g[16];
            size_t n = garbage(g), k;
            voxhap_host_msg ignored;
            for (k = 0; k < n; k++) voxhap_decoder_push_host(&p.fw.decoder, g[k], &ignored); /* into the receiver */
            fwlog_event(&p.log, 'X', "garbage_rx", (uint32_t)n, t);
            n = garbage(g);
            uart_write(&p, g, n); /* onto the line, between two whole frames */
            fwlog_event(&p.log, 'X', "garbage_tx", (uint32_t)n, t);
            next_garbage = t + (uint64_t)(garbage_ms * 1000);
        }
        /* Control at 1 kHz, and at once when bytes came in (lowest reply latency). */
        if ((pfd.revents & POLLIN) || t >= next_control) {
            voxhap_fw_tick(&p.fw);
            /* logged with the control cycle's own time, after its replies (a watchdog Fault comes first) */
            fwlog_applied(&p.log, p.fw.applied_n, p.fw.last_control_us);
            if (t >= next_control) {
                next_control += 1000;
                if (next_control <= t) next_control = t + 1000; /* fell behind: skip, never burst */
            }
        }
        if (t >= next_flush) {
            fflush(p.log_file);
            next_flush = t + 20000;
        }
    }
    {
        float zero[3] = {0, 0, 0};
        write_force(&p, zero);
        fwlog_applied(&p.log, zero, now_us(&p));
    }
    fwlog_event(&p.log, 'X', "exit", 0, now_us(&p));
    fclose(p.log_file);
    printf("stopped: frames ok %u, dropped: cobs %u, oversize %u, too short %u, crc %u, unknown type %u, "
           "bad length %u, invalid value %u; watchdog trips %u, forces ignored %u, outbox overflows %u, "
           "tx bytes dropped %u\n",
           p.fw.decoder.stats.frames_ok, p.fw.decoder.stats.cobs_errors, p.fw.decoder.stats.oversize,
           p.fw.decoder.stats.too_short, p.fw.decoder.stats.crc_errors, p.fw.decoder.stats.unknown_type,
           p.fw.decoder.stats.bad_length, p.fw.decoder.stats.invalid_value, p.fw.session.stats.watchdog_trips,
           p.fw.session.stats.forces_ignored, p.fw.session.stats.outbox_overflows, p.tx_dropped);
    close_pty(&p);
    if (p.link) unlink(p.link);
    return 0;
}
