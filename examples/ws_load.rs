//! Does a crowd of visualisers slow the servo? Runs the simulated arm at 1 kHz with the visualiser server, and
//! compares the servo's tick lateness with no WebSocket clients and with N clients streaming at 60 Hz that read
//! everything, in alternating runs (a fresh session each run, the server up in both).
//!
//! ```text
//! cargo run --release --example ws_load -- [--clients 100] [--seconds 5] [--pairs 3] [--rate 60]
//! ```
//!
//! The server runs on its own 2-worker tokio runtime (as in `voxhap serve`); the clients on another, so the
//! comparison includes the CPU the clients themselves take on the same machine. A run's statistics cover the
//! whole session, including connecting the clients.

use clap::Parser;
use futures_util::StreamExt;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use voxhap::server::{self, ServerConfig};
use voxhap::servo::device::DeviceSpec;
use voxhap::servo::rt::{self, RtMode};
use voxhap::servo::setup::SceneSetup;
use voxhap::servo::{SessionApi, SessionConfig, StatsReport};

#[derive(Debug, Parser)]
struct Args {
    /// WebSocket clients in the loaded runs.
    #[arg(long, default_value_t = 100)]
    clients: usize,
    /// Length of each run (s).
    #[arg(long, default_value_t = 5.0)]
    seconds: f64,
    /// Pairs of runs (no clients, then N clients).
    #[arg(long, default_value_t = 3)]
    pairs: usize,
    /// State rate each client asks for (Hz).
    #[arg(long, default_value_t = 60)]
    rate: u32,
}

struct RunResult {
    stats: StatsReport,
    /// State messages the clients received, per client per second.
    received_hz: f64,
    frames_dropped: u64,
}

/// Lets the calling thread run on every CPU (undoing an inherited `reserve_servo_cpu`).
fn allow_every_cpu() {
    let every: Vec<usize> = (0..rt::online_cpus()).collect();
    let _ = rt::set_thread_affinity(&every);
}

fn run_once(args: &Args, clients: usize) -> anyhow::Result<RunResult> {
    // Undo the previous run's reservation on this (main) thread. As `voxhap serve` does, the server's threads
    // then stay off the servo's core; the clients stand for other processes (browsers, scripts), which may run
    // on any core, so their runtime is started first and its threads allowed every CPU.
    allow_every_cpu();
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
    let api: Arc<dyn SessionApi> = session.api();
    let listener = server_rt.block_on(tokio::net::TcpListener::bind("127.0.0.1:0"))?;
    let addr = listener.local_addr()?;
    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    let server_config = ServerConfig {
        token: server::config::random_token()?,
        max_clients: clients + 1,
        idle_timeout: server::config::DEFAULT_IDLE_TIMEOUT,
    };
    let server = server_rt.spawn(server::run(
        listener,
        api.clone(),
        server_config,
        async move {
            let _ = stop_rx.await;
        },
    ));

    let received = Arc::new(AtomicU64::new(0));
    let started = Instant::now();
    let mut readers = Vec::with_capacity(clients);
    for _ in 0..clients {
        let url = format!("ws://{addr}/ws?rate={}", args.rate);
        let received = received.clone();
        readers.push(client_rt.spawn(async move {
            let Ok((mut ws, _)) = tokio_tungstenite::connect_async(url).await else {
                return;
            };
            while let Some(Ok(message)) = ws.next().await {
                if message.is_text() {
                    received.fetch_add(1, Ordering::Relaxed);
                }
            }
        }));
    }
    std::thread::sleep(Duration::from_secs_f64(args.seconds));
    let elapsed = started.elapsed().as_secs_f64();
    let counters = server_rt.block_on(server_counters(addr));
    let _ = stop_tx.send(());
    let _ = server_rt.block_on(server);
    for reader in readers {
        reader.abort();
    }
    let summary = session.stop();
    let total = received.load(Ordering::Relaxed) as f64;
    Ok(RunResult {
        stats: summary.stats,
        received_hz: if clients == 0 {
            0.0
        } else {
            total / clients as f64 / elapsed
        },
        frames_dropped: counters["server"]["frames_dropped"].as_u64().unwrap_or(0),
    })
}

/// `GET /api/stats` over a plain TCP connection (the server's own counters).
async fn server_counters(addr: std::net::SocketAddr) -> serde_json::Value {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let Ok(mut stream) = tokio::net::TcpStream::connect(addr).await else {
        return serde_json::Value::Null;
    };
    let request = format!("GET /api/stats HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n");
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

fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    println!(
        "ws_load: simulated arm at 1 kHz, visualiser server up; {} pairs of {} s runs: 0 clients, then {} clients at {} Hz",
        args.pairs, args.seconds, args.clients, args.rate
    );
    println!(
        "{:>4} {:>7} {:>9} {:>9} {:>9} {:>9} {:>9} {:>11} {:>8}",
        "pair",
        "clients",
        "p50 us",
        "p99 us",
        "p99.9 us",
        "max us",
        "overruns",
        "recv Hz/cl",
        "dropped"
    );
    let mut idle = Vec::new();
    let mut loaded = Vec::new();
    for pair in 0..args.pairs {
        for clients in [0, args.clients] {
            let result = run_once(&args, clients)?;
            let l = result.stats.lateness;
            println!(
                "{:>4} {:>7} {:>9.1} {:>9.1} {:>9.1} {:>9.1} {:>9} {:>11.1} {:>8}",
                pair + 1,
                clients,
                l.p50_us,
                l.p99_us,
                l.p999_us,
                l.max_us,
                result.stats.overruns,
                result.received_hz,
                result.frames_dropped
            );
            if clients == 0 {
                idle.push(result.stats);
            } else {
                loaded.push(result.stats);
            }
        }
    }
    let pick =
        |runs: &[StatsReport], f: fn(&StatsReport) -> f64| median(runs.iter().map(f).collect());
    println!(
        "median over pairs   0 clients  {:>4} clients   ratio",
        args.clients
    );
    for (name, f) in [
        (
            "p50 us",
            (|s: &StatsReport| s.lateness.p50_us) as fn(&StatsReport) -> f64,
        ),
        ("p99 us", |s: &StatsReport| s.lateness.p99_us),
        ("p99.9 us", |s: &StatsReport| s.lateness.p999_us),
    ] {
        let (a, b) = (pick(&idle, f), pick(&loaded, f));
        println!(
            "{name:<18} {a:>10.1} {b:>13.1} {:>7.2}",
            if a > 0.0 { b / a } else { f64::NAN }
        );
    }
    if let Some(first) = idle.first() {
        let rt = first.realtime;
        println!(
            "real time: SCHED_FIFO {}, memory locked {}, pinned CPU {:?}",
            rt.sched_fifo, rt.memory_locked, rt.pinned_cpu
        );
    }
    Ok(())
}
