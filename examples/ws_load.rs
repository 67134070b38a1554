//! Does a crowd of visualisers slow the servo? Runs the simulated arm at 1 kHz with the visualiser server and
//! compares the servo's tick lateness with no WebSocket clients and with N clients streaming at 60 Hz that read
//! everything.
//!
//! ```text
//! cargo run --release --example ws_load -- [--clients 100] [--rate 60] [--pairs 20] [--block-seconds 3]
//! ```
//!
//! One session and one server run throughout; the clients come and go. The run is a series of block pairs,
//! one block with no clients and one with N, in the order AB BA AB ... so that a slow drift of the machine
//! (other guests on a shared host, say) weighs on both conditions alike. In a loaded block all N clients are
//! connected and streaming before the block's window opens, and they are dropped after it closes; each window
//! is a copy of the servo's lateness histogram taken at its two edges, so both conditions are measured on the
//! same servo thread in the same session. The windows of each condition are pooled, and the pooled p99s
//! compared. A 90 % bootstrap interval (block pairs resampled with replacement) says how far the ratio can be
//! trusted: the verdict is "met" when the whole interval is at or below 1.10, "not met" when it is all above,
//! and "undecided" otherwise (always with fewer than 10 pairs). It also prints the share of ticks more than 10 µs late, with its interval:
//! when about 1 % of ticks are late the p99 sits on a cliff between on-time and late ticks and jumps, while
//! that share stays steady. `--interfere-us 60` is the self-check: the loaded windows also get a thread above
//! the servo's priority busying its core, a known cost the verdict must call "not met".
//!
//! The server runs on its own 2-worker tokio runtime kept off the servo's core, as in `voxhap serve`; the
//! clients on another runtime allowed every CPU, standing for browsers and scripts on the same machine, so the
//! comparison includes the CPU the clients themselves take.

use clap::Parser;
use futures_util::StreamExt;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use voxhap::server::{self, ServerConfig};
use voxhap::servo::device::DeviceSpec;
use voxhap::servo::rt::{self, RtMode};
use voxhap::servo::setup::SceneSetup;
use voxhap::servo::stats::HistogramCounts;
use voxhap::servo::{SessionApi, SessionConfig, SessionShared};

/// The criterion: lateness p99 with the clients at most this times the figure without them.
const CRITERION: f64 = 1.10;
/// Fewer pairs than this give no verdict: resampling a handful of pairs says nothing about the spread.
const MIN_PAIRS: usize = 10;
/// Ticks later than this are counted as "late" in the table (ns).
const LATE_NS: u64 = 10_000;

#[derive(Debug, Parser)]
struct Args {
    /// WebSocket clients in the loaded blocks.
    #[arg(long, default_value_t = 100)]
    clients: usize,
    /// State rate each client asks for (Hz).
    #[arg(long, default_value_t = 60)]
    rate: u32,
    /// Block pairs (one block without clients, one with).
    #[arg(long, default_value_t = 20)]
    pairs: usize,
    /// Length of each block's measured window (s).
    #[arg(long, default_value_t = 3.0)]
    block_seconds: f64,
    /// Wait after the clients connect, and after they leave, before the next window (s).
    #[arg(long, default_value_t = 0.5)]
    settle_seconds: f64,
    /// Time the session runs before the first window (its first seconds are slower: pages, caches) (s).
    #[arg(long, default_value_t = 2.0)]
    warmup_seconds: f64,
    /// Self-check: in the loaded blocks, also run a thread at a higher real-time priority on the servo's
    /// core that busies it this long (µs) every 2.9 ms, a known slowdown the comparison must report as
    /// "not met" (0: off; needs the privilege to use SCHED_FIFO).
    #[arg(long, default_value_t = 0.0)]
    interfere_us: f64,
    /// Bootstrap resamples for the interval.
    #[arg(long, default_value_t = 2000)]
    resamples: usize,
}

/// One measured window.
struct Block {
    clients: usize,
    lateness: HistogramCounts,
    /// State messages the clients received in the window, per client per second.
    received_hz: f64,
    /// Frames the server dropped for slow clients in the window.
    frames_dropped: u64,
}

/// Lets the calling thread run on every CPU (undoing an inherited `reserve_servo_cpu`).
fn allow_every_cpu() {
    let every: Vec<usize> = (0..rt::online_cpus()).collect();
    let _ = rt::set_thread_affinity(&every);
}

struct Bench {
    args: Args,
    client_rt: tokio::runtime::Runtime,
    server_rt: tokio::runtime::Runtime,
    shared: Arc<SessionShared>,
    addr: std::net::SocketAddr,
    /// On in the loaded windows when the self-check (`--interfere-us`) runs.
    interference: Arc<std::sync::atomic::AtomicBool>,
}

/// A thread that, while `on`, preempts the servo on its core for `busy` every 2.9 ms (SCHED_FIFO priority
/// above the servo's). Returns an error when it cannot get that priority: the self-check would be empty.
fn start_interference(
    cpu: usize,
    busy: Duration,
    on: Arc<std::sync::atomic::AtomicBool>,
) -> anyhow::Result<()> {
    let (ready_tx, ready_rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let param = libc::sched_param {
            sched_priority: rt::FIFO_PRIORITY + 5,
        };
        // SAFETY: valid pointer to a sched_param; pid 0 is the calling thread.
        let fifo = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) } == 0;
        let pinned = rt::set_thread_affinity(&[cpu]).is_ok();
        let _ = ready_tx.send(fifo && pinned);
        if !(fifo && pinned) {
            return;
        }
        loop {
            std::thread::sleep(Duration::from_micros(2900).saturating_sub(busy));
            if on.load(Ordering::Relaxed) {
                let start = Instant::now();
                while start.elapsed() < busy {
                    std::hint::spin_loop();
                }
            }
        }
    });
    anyhow::ensure!(
        ready_rx.recv().unwrap_or(false),
        "--interfere-us needs SCHED_FIFO and a pinned core (run as root or grant rtprio)"
    );
    Ok(())
}

impl Bench {
    /// Measures one window with `clients` streaming clients.
    fn block(&self, clients: usize) -> anyhow::Result<Block> {
        let received = Arc::new(AtomicU64::new(0));
        let streaming = Arc::new(AtomicUsize::new(0));
        let mut readers = Vec::with_capacity(clients);
        for _ in 0..clients {
            let url = format!("ws://{}/ws?rate={}", self.addr, self.args.rate);
            let (received, streaming) = (received.clone(), streaming.clone());
            readers.push(self.client_rt.spawn(async move {
                let Ok((mut ws, _)) = tokio_tungstenite::connect_async(url).await else {
                    return;
                };
                let mut first = true;
                while let Some(Ok(message)) = ws.next().await {
                    if message.is_text() {
                        received.fetch_add(1, Ordering::Relaxed);
                        if std::mem::take(&mut first) {
                            streaming.fetch_add(1, Ordering::Relaxed);
                        }
                    }
                }
            }));
        }
        let deadline = Instant::now() + Duration::from_secs(20);
        while streaming.load(Ordering::Relaxed) < clients {
            anyhow::ensure!(
                Instant::now() < deadline,
                "only {} of {clients} clients streaming after 20 s",
                streaming.load(Ordering::Relaxed)
            );
            std::thread::sleep(Duration::from_millis(10));
        }
        self.interference.store(clients > 0, Ordering::Relaxed);
        std::thread::sleep(Duration::from_secs_f64(self.args.settle_seconds));

        let dropped_before = self.frames_dropped();
        let received_before = received.load(Ordering::Relaxed);
        let lateness_before = self.shared.servo_stats().lateness.counts();
        let started = Instant::now();
        std::thread::sleep(Duration::from_secs_f64(self.args.block_seconds));
        let lateness = self
            .shared
            .servo_stats()
            .lateness
            .counts()
            .since(&lateness_before);
        let elapsed = started.elapsed().as_secs_f64();
        let received_in_window = received.load(Ordering::Relaxed) - received_before;
        let frames_dropped = self.frames_dropped().saturating_sub(dropped_before);

        self.interference.store(false, Ordering::Relaxed);
        for reader in readers {
            reader.abort();
        }
        std::thread::sleep(Duration::from_secs_f64(self.args.settle_seconds));
        Ok(Block {
            clients,
            lateness,
            received_hz: if clients == 0 {
                0.0
            } else {
                received_in_window as f64 / clients as f64 / elapsed
            },
            frames_dropped,
        })
    }

    /// The server's `frames_dropped` counter, from `GET /api/stats` over a plain TCP connection.
    fn frames_dropped(&self) -> u64 {
        let stats = self.server_rt.block_on(get_json(self.addr, "/api/stats"));
        stats["server"]["frames_dropped"].as_u64().unwrap_or(0)
    }
}

async fn get_json(addr: std::net::SocketAddr, path: &str) -> serde_json::Value {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let Ok(mut stream) = tokio::net::TcpStream::connect(addr).await else {
        return serde_json::Value::Null;
    };
    let request = format!("GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n");
    let mut response = Vec::new();
    if stream.write_all(request.as_bytes()).await.is_err()
        || stream.read_to_end(&mut response).await.is_err()
    {
        return serde_json::Value::Null;
    }
    let text = String::from_utf8_lossy(&response);
    text.split_once("\r\n\r\n")
        .and_then(|(_, body)| serde_json::from_str(body).ok())
        .unwrap_or(serde_json::Value::Null)
}

/// The pairs `picks` pooled: (no clients, with clients).
fn pool(
    pairs: &[(Block, Block)],
    picks: impl Iterator<Item = usize>,
) -> (HistogramCounts, HistogramCounts) {
    let (mut idle, mut loaded) = (HistogramCounts::default(), HistogramCounts::default());
    for i in picks {
        idle.add(&pairs[i].0.lateness);
        loaded.add(&pairs[i].1.lateness);
    }
    (idle, loaded)
}

/// The share of ticks more than 10 µs late.
fn late_share(h: &HistogramCounts) -> f64 {
    h.count_above_ns(LATE_NS) as f64 / h.count().max(1) as f64
}

fn us(ns: u64) -> f64 {
    ns as f64 / 1000.0
}

/// xorshift64*: enough for resampling indices, and no dependency.
struct Rng(u64);

impl Rng {
    fn below(&mut self, n: usize) -> usize {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 33) as usize % n
    }
}

/// A statistic of the two conditions' pooled histograms (idle, loaded).
type Statistic = fn(&HistogramCounts, &HistogramCounts) -> f64;

/// Loaded p99 over idle p99.
fn p99_ratio(idle: &HistogramCounts, loaded: &HistogramCounts) -> f64 {
    us(loaded.quantile_ns(0.99)) / us(idle.quantile_ns(0.99)).max(1e-3)
}

/// Loaded over idle share of ticks more than 10 µs late.
fn late_ratio(idle: &HistogramCounts, loaded: &HistogramCounts) -> f64 {
    late_share(loaded) / late_share(idle).max(1e-9)
}

/// `statistic` of all pairs pooled, and its 90 % bootstrap interval (pairs resampled with replacement).
fn bootstrap(pairs: &[(Block, Block)], resamples: usize, statistic: Statistic) -> (f64, f64, f64) {
    let n = pairs.len();
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let mut values: Vec<f64> = (0..resamples.max(1))
        .map(|_| {
            let (idle, loaded) = pool(pairs, (0..n).map(|_| rng.below(n)));
            statistic(&idle, &loaded)
        })
        .collect();
    values.sort_by(f64::total_cmp);
    let at = |q: f64| values[(q * (values.len() - 1) as f64).round() as usize];
    let (idle, loaded) = pool(pairs, 0..n);
    (statistic(&idle, &loaded), at(0.05), at(0.95))
}

fn print_block(pair: usize, block: &Block) {
    let l = &block.lateness;
    println!(
        "{:>4} {:>7} {:>8} {:>8.2} {:>8.1} {:>9.1} {:>8} {:>10.1} {:>8}",
        pair + 1,
        block.clients,
        l.count(),
        us(l.quantile_ns(0.5)),
        us(l.quantile_ns(0.99)),
        us(l.quantile_ns(0.999)),
        l.count_above_ns(LATE_NS),
        block.received_hz,
        block.frames_dropped
    );
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    anyhow::ensure!(
        args.pairs > 0 && args.block_seconds > 0.0,
        "--pairs and --block-seconds must be positive"
    );
    // The clients stand for other processes (browsers, scripts), which may run on any core: their runtime is
    // started before the servo's core is reserved, and its threads allowed every CPU.
    let client_rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .on_thread_start(allow_every_cpu)
        .enable_all()
        .build()?;
    let servo_cpu = rt::reserve_servo_cpu(RtMode::BestEffort, None).map(|(cpu, _)| cpu);
    let server_rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    let mut config = SessionConfig::new(DeviceSpec::Sim, SceneSetup::builtin()?);
    config.cpu = servo_cpu.or(config.cpu);
    let session = voxhap::servo::Session::start(config)?;
    let shared = session.api();
    let api: Arc<dyn SessionApi> = shared.clone();
    let listener = server_rt.block_on(tokio::net::TcpListener::bind("127.0.0.1:0"))?;
    let addr = listener.local_addr()?;
    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    let server_config = ServerConfig {
        token: server::config::random_token()?,
        max_clients: args.clients + 1,
        idle_timeout: server::config::DEFAULT_IDLE_TIMEOUT,
        header_timeout: server::config::DEFAULT_HEADER_TIMEOUT,
        allowed_hosts: Vec::new(),
        allowed_origins: Vec::new(),
    };
    let server = server_rt.spawn(server::run(listener, api, server_config, async move {
        let _ = stop_rx.await;
    }));

    println!(
        "ws_load: simulated arm at 1 kHz, visualiser server up; {} block pairs of {} s windows (AB BA ...): \
         0 clients and {} clients at {} Hz",
        args.pairs, args.block_seconds, args.clients, args.rate
    );
    println!(
        "{:>4} {:>7} {:>8} {:>8} {:>8} {:>9} {:>8} {:>10} {:>8}",
        "pair",
        "clients",
        "ticks",
        "p50 us",
        "p99 us",
        "p99.9 us",
        ">10us",
        "recv Hz/cl",
        "dropped"
    );
    let bench = Bench {
        args,
        client_rt,
        server_rt,
        shared,
        addr,
        interference: Arc::new(std::sync::atomic::AtomicBool::new(false)),
    };
    if bench.args.interfere_us > 0.0 {
        let cpu = servo_cpu.ok_or_else(|| {
            anyhow::anyhow!("--interfere-us needs the servo on a core of its own")
        })?;
        start_interference(
            cpu,
            Duration::from_secs_f64(bench.args.interfere_us * 1e-6),
            bench.interference.clone(),
        )?;
        println!(
            "self-check: loaded blocks also busy the servo's core {} us every 2.9 ms",
            bench.args.interfere_us
        );
    }
    std::thread::sleep(Duration::from_secs_f64(bench.args.warmup_seconds));
    let mut pairs = Vec::with_capacity(bench.args.pairs);
    for pair in 0..bench.args.pairs {
        let order = if pair % 2 == 0 {
            [0, bench.args.clients]
        } else {
            [bench.args.clients, 0]
        };
        let first = bench.block(order[0])?;
        print_block(pair, &first);
        let second = bench.block(order[1])?;
        print_block(pair, &second);
        pairs.push(if first.clients == 0 {
            (first, second)
        } else {
            (second, first)
        });
    }

    let (idle, loaded) = pool(&pairs, 0..pairs.len());
    println!(
        "pooled            0 clients  {:>4} clients   ratio",
        bench.args.clients
    );
    for (name, q) in [("p50 us", 0.5), ("p99 us", 0.99), ("p99.9 us", 0.999)] {
        let (a, b) = (us(idle.quantile_ns(q)), us(loaded.quantile_ns(q)));
        println!("{name:<17} {a:>10.2} {b:>13.2} {:>7.2}", b / a.max(1e-3));
    }
    println!(
        "ticks > 10 us late {:>9.3}% {:>12.3}%",
        100.0 * late_share(&idle),
        100.0 * late_share(&loaded)
    );
    let higher = pairs
        .iter()
        .filter(|(a, b)| b.lateness.quantile_ns(0.99) > a.lateness.quantile_ns(0.99))
        .count();
    let (ratio, low, high) = bootstrap(&pairs, bench.args.resamples, p99_ratio);
    let verdict = if pairs.len() < MIN_PAIRS {
        "undecided (fewer than 10 pairs: too few to resample)"
    } else if high <= CRITERION {
        "met"
    } else if low > CRITERION {
        "not met"
    } else {
        "undecided (the machine is too noisy for this many pairs)"
    };
    println!(
        "p99 ratio {ratio:.2}, 90% bootstrap interval [{low:.2}, {high:.2}]; loaded p99 higher in {higher} of {} \
         pairs; criterion <= {CRITERION:.2}: {verdict}",
        pairs.len()
    );
    // The p99 sits on a cliff when about 1 % of ticks are late (the rest are on time to within a
    // microsecond), and then jumps between the two sides from one resample to the next; the share of late
    // ticks is the well-conditioned figure underneath it.
    let (ratio, low, high) = bootstrap(&pairs, bench.args.resamples, late_ratio);
    println!(
        "share of ticks > 10 us late: ratio {ratio:.2}, 90% bootstrap interval [{low:.2}, {high:.2}]"
    );
    let rt = bench.shared.stats().realtime;
    println!(
        "real time: SCHED_FIFO {}, memory locked {}, pinned CPU {:?}",
        rt.sched_fifo, rt.memory_locked, rt.pinned_cpu
    );

    let _ = stop_tx.send(());
    let _ = bench.server_rt.block_on(server);
    let summary = session.stop();
    println!(
        "whole session: {} ticks, overruns {}, recorder drops {}",
        summary.stats.ticks, summary.stats.overruns, summary.stats.recorder_drops
    );
    Ok(())
}
