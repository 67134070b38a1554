//! `serve`'s `--ros2` output: its flags, start and stop, behind the `ros2` cargo feature (on by default).
//!
//! Built without the feature (as the fuzz workspace builds the crate, so it compiles no DDS stack), the flags do
//! not exist and nothing here starts a thread; `serve` calls the same three functions either way.

use crate::servo::Session;

#[cfg(feature = "ros2")]
pub use voxhap_ros2::Ros2Args;

/// Without the `ros2` feature: no `--ros2` flags.
#[cfg(not(feature = "ros2"))]
#[derive(Debug, Clone, Default, clap::Args)]
pub struct Ros2Args {}

/// What [`resolve`] checked: the ROS 2 settings (a type with no values when built without the feature).
#[cfg(feature = "ros2")]
pub type Settings = voxhap_ros2::Ros2Settings;
/// What [`resolve`] checked: the ROS 2 settings (a type with no values when built without the feature).
#[cfg(not(feature = "ros2"))]
pub type Settings = std::convert::Infallible;

/// The running output, stopped by [`stop`].
#[cfg(feature = "ros2")]
pub type Running = voxhap_ros2::Ros2Output;
/// The running output, stopped by [`stop`] (a type with no values when built without the feature).
#[cfg(not(feature = "ros2"))]
pub type Running = std::convert::Infallible;

/// Checks the `--ros2` flags; `None` when the output is off.
pub fn resolve(args: &Ros2Args) -> anyhow::Result<Option<Settings>> {
    #[cfg(feature = "ros2")]
    {
        Ok(args.resolve()?)
    }
    #[cfg(not(feature = "ros2"))]
    {
        let Ros2Args {} = args;
        Ok(None)
    }
}

/// True when `--ros2` is given.
pub fn enabled(args: &Ros2Args) -> bool {
    #[cfg(feature = "ros2")]
    {
        args.ros2
    }
    #[cfg(not(feature = "ros2"))]
    {
        let Ros2Args {} = args;
        false
    }
}

/// Starts the ROS 2 output when `--ros2` is given, fed by the session's snapshots; with `external_force`
/// (`--external-force`) it also takes `/voxhap/servo_cf` wrenches into the session's external force input.
pub fn start(
    settings: Option<Settings>,
    rate_hz: f64,
    session: &Session,
    external_force: bool,
) -> anyhow::Result<Option<Running>> {
    let Some(settings) = settings else {
        return Ok(None);
    };
    #[cfg(feature = "ros2")]
    {
        let api = session.api();
        let sink: Option<voxhap_ros2::ExternalForceSink> = external_force.then(|| {
            let api = session.api();
            let sink: voxhap_ros2::ExternalForceSink = Box::new(move |force_n| {
                crate::api::SessionApi::control(
                    &*api,
                    crate::api::ControlCommand::SetExternalForce { force_n },
                )
                .map(|_| ())
            });
            sink
        });
        let output = voxhap_ros2::Ros2Output::start_with_servo_cf(
            settings,
            rate_hz,
            Box::new(move || crate::api::SessionApi::snapshot(&*api)),
            sink,
        )?;
        super::common::print_out(&format!(
            "ros2: publishing /voxhap/measured_cp, measured_cv, measured_cf, setpoint_cf, operating_state on domain {} at {:.1} Hz{}",
            settings.domain_id,
            1.0 / output.period().as_secs_f64(),
            if settings.localhost_only { " (localhost only)" } else { "" }
        ))?;
        if external_force {
            super::common::print_out(
                "ros2: subscribed to /voxhap/servo_cf (geometry_msgs/msg/WrenchStamped, best effort): its force is the external force",
            )?;
        }
        Ok(Some(output))
    }
    #[cfg(not(feature = "ros2"))]
    {
        let _ = (rate_hz, session, external_force);
        match settings {}
    }
}

/// Stops the output and prints what it published.
pub fn stop(running: Running) -> anyhow::Result<()> {
    #[cfg(feature = "ros2")]
    {
        let published = running.stop();
        super::common::print_out(&format!(
            "ros2: {} ticks published, {} writes dropped",
            published.ticks_published, published.failed_writes
        ))?;
        if let Some(servo_cf) = published.servo_cf {
            super::common::print_out(&format!(
                "ros2: /voxhap/servo_cf: {} wrenches taken, {} refused, {} with a torque ignored",
                servo_cf.taken, servo_cf.refused, servo_cf.torque_ignored
            ))?;
        }
        Ok(())
    }
    #[cfg(not(feature = "ros2"))]
    {
        match running {}
    }
}
