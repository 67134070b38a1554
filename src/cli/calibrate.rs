//! `voxhap calibrate`: measure the box the handle really reaches and write it as a device profile.
//!
//! Where it sits: a command of its own, before `serve`. It opens the device under the supervisor (the full
//! safety pipeline; it only ever commands zero force), tells the user to move the handle to every limit of its
//! workspace, records the smallest and largest position of every accepted sample for `--seconds`, and writes a
//! profile: `[workspace]` with the measured box (which `--fit-volume` then fits instead of the device's
//! declared box), and a `[mapping]` whose translation puts the middle of the measured box on the scene origin.
//! For a device with a built-in profile the file starts from it (`base = "..."`), so its kinematics stay.
//! An existing file is never replaced without `--force`.

use crate::device::profile::{builtin_text, DeviceProfile};
use crate::device::supervisor::{SupervisorConfig, TickClock, TickInput};
use crate::servo::device::{open_device, spec_family, DeviceSpec};
use anyhow::Context;
use glam::DVec3;
use std::io::Write;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// Fewest accepted samples a calibration needs.
pub const MIN_SAMPLES: u64 = 100;

/// `voxhap calibrate` flags.
#[derive(Debug, clap::Args)]
pub struct CalibrateArgs {
    /// The device, as for `serve --device` (sim, haply2diy:PATH, haply-inverse, falcon, ...).
    #[arg(long, default_value = "sim")]
    pub device: DeviceSpec,
    /// Where to write the profile (TOML).
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
    /// Replace FILE if it exists.
    #[arg(long)]
    pub force: bool,
    /// How long to record (s): move the handle to every limit of its workspace meanwhile.
    #[arg(long, default_value_t = 20.0, value_parser = super::common::parse_seconds)]
    pub seconds: f64,
    /// The profile's name (default: "calibrated DEVICE").
    #[arg(long)]
    pub name: Option<String>,
}

/// The box the accepted samples span.
#[derive(Debug, Clone, Copy)]
struct Extents {
    min_m: DVec3,
    max_m: DVec3,
    samples: u64,
}

impl Extents {
    fn new() -> Extents {
        Extents {
            min_m: DVec3::splat(f64::INFINITY),
            max_m: DVec3::splat(f64::NEG_INFINITY),
            samples: 0,
        }
    }

    fn add(&mut self, position_m: DVec3) {
        if position_m.is_finite() {
            self.min_m = self.min_m.min(position_m);
            self.max_m = self.max_m.max(position_m);
            self.samples += 1;
        }
    }
}

/// The profile text for the measured box.
fn profile_text(name: &str, family: &str, extents: &Extents, seconds: f64) -> String {
    let centre = (extents.min_m + extents.max_m) / 2.0;
    let mut text = format!(
        "# Written by `voxhap calibrate --device {family}`: {} samples over {seconds} s.\n\
         name = {name:?}\n\
         device = {family:?}\n",
        extents.samples
    );
    if builtin_text(family).is_some() {
        text.push_str(&format!("base = {family:?}\n"));
    }
    // + 0.0 turns -0.0 into 0.0.
    let v = |v: DVec3| format!("[{:.6}, {:.6}, {:.6}]", v.x + 0.0, v.y + 0.0, v.z + 0.0);
    text.push_str(&format!(
        "\n# The box the handle reached (device frame, m); --fit-volume fits this box.\n\
         [workspace]\nmin_m = {}\nmax_m = {}\n\n\
         # The middle of that box on the scene origin, 1 scene metre per device metre.\n\
         [mapping]\nscale = 1.0\ntranslation_m = {}\n",
        v(extents.min_m),
        v(extents.max_m),
        v(-centre)
    ));
    text
}

/// Runs the calibration.
pub fn run(args: &CalibrateArgs) -> anyhow::Result<()> {
    if args.out.exists() && !args.force {
        anyhow::bail!(
            "{} exists; give --force to replace it, or another --out",
            args.out.display()
        );
    }
    let family = spec_family(&args.device);
    let period = Duration::from_millis(1);
    let arm = crate::device::mock::default_arm_config();
    let start_m = arm.path.target_at(0.0).unwrap_or(DVec3::ZERO);
    let mut device = open_device(
        &args.device,
        SupervisorConfig::default(),
        (arm, start_m),
        period.as_secs_f64(),
    )
    .with_context(|| format!("device {}", args.device))?
    .device;
    device
        .connect(0)
        .with_context(|| format!("device {}: could not connect", args.device))?;
    super::common::print_out(&format!(
        "calibrating {}: move the handle slowly to every limit of its workspace (left, right, front, back, \
         up, down) for {} s; no force is applied",
        args.device, args.seconds
    ))?;
    let started = Instant::now();
    let mut extents = Extents::new();
    let mut next_report_s = 1.0;
    let mut tick: u64 = 0;
    while started.elapsed().as_secs_f64() < args.seconds {
        tick += 1;
        let out = device.exchange(TickInput {
            force_n: DVec3::ZERO,
            now_us: started.elapsed().as_micros() as u64,
            clock: TickClock::Monotonic,
            on_time: true,
            force_valid: false,
            local: None,
        });
        if let (Some(state), false) = (out.state, out.stale) {
            extents.add(state.position_m);
        }
        let elapsed_s = started.elapsed().as_secs_f64();
        if elapsed_s >= next_report_s && extents.samples > 0 {
            next_report_s += 1.0;
            let size = extents.max_m - extents.min_m;
            super::common::print_out(&format!(
                "  {elapsed_s:4.0} s: box {:.1} x {:.1} x {:.1} mm from {} samples",
                size.x * 1e3,
                size.y * 1e3,
                size.z * 1e3,
                extents.samples
            ))?;
        }
        let deadline = started + period * (tick as u32).max(1);
        if let Some(wait) = deadline.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
    }
    device.stop();
    if extents.samples < MIN_SAMPLES {
        anyhow::bail!(
            "only {} usable samples from {} in {} s (at least {MIN_SAMPLES} are needed); nothing written",
            extents.samples,
            args.device,
            args.seconds
        );
    }
    if extents.min_m == extents.max_m {
        anyhow::bail!(
            "the handle did not move (every sample at {:?} m); nothing written",
            extents.min_m.to_array()
        );
    }
    let name = args
        .name
        .clone()
        .unwrap_or_else(|| format!("calibrated {family}"));
    let text = profile_text(&name, &family, &extents, args.seconds);
    // The file must read back as a profile before it is written.
    DeviceProfile::parse(&text, &args.out.display().to_string())
        .context("the calibrated profile does not check (a bug)")?;
    // Never through a symlink: O_EXCL refuses one, and with --force O_NOFOLLOW does.
    let mut file = if args.force {
        crate::record::create_or_replace_file(&args.out).map_err(anyhow::Error::from)
    } else {
        std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&args.out)
            .map_err(anyhow::Error::from)
    }
    .with_context(|| format!("{}: could not create", args.out.display()))?;
    file.write_all(text.as_bytes())
        .and_then(|()| file.sync_all())
        .with_context(|| format!("{}: could not write", args.out.display()))?;
    let size = extents.max_m - extents.min_m;
    super::common::print_out(&format!(
        "wrote {}: workspace {:.1} x {:.1} x {:.1} mm; use it with `voxhap serve --device {} --device-profile {}`",
        args.out.display(),
        size.x * 1e3,
        size.y * 1e3,
        size.z * 1e3,
        args.device,
        args.out.display()
    ))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_written_profile_parses_and_fits_the_measured_box() {
        let mut extents = Extents::new();
        extents.add(DVec3::new(-0.05, 0.02, 0.0));
        extents.add(DVec3::new(0.05, 0.14, 0.0));
        extents.add(DVec3::new(f64::NAN, 0.0, 0.0));
        assert_eq!(extents.samples, 2);
        let text = profile_text("bench", "haply2diy", &extents, 20.0);
        let mut profile = DeviceProfile::parse(&text, "calibrated").unwrap();
        assert_eq!(profile.device.as_deref(), Some("haply2diy"));
        // It kept the built-in's kinematics through `base`.
        assert_ne!(
            profile.kinematics,
            crate::device::profile::Kinematics::Default
        );
        let centre = profile
            .mapping_for(DVec3::ZERO, DVec3::ONE, None)
            .unwrap()
            .to_scene_position_m(DVec3::new(0.0, 0.08, 0.0));
        assert!(centre.length() < 1e-9, "{centre}");
        profile.mapping = crate::device::profile::MappingChoice::FitVolume {
            rotation: glam::DMat3::IDENTITY,
        };
        let fitted = profile
            .mapping_for(
                DVec3::splat(-1.0),
                DVec3::splat(1.0),
                Some((DVec3::splat(-0.1), DVec3::splat(0.1))),
            )
            .unwrap();
        assert!((fitted.scale() - 2.0).abs() < 1e-9, "{}", fitted.scale());
    }
}
