//! Building a device from a spec ([`open_device`]): picks the driver and transport for a [`DeviceSpec`],
//! wraps it in a [`Supervisor`] (directly for in-process devices, through [`Reconnecting`] for devices that
//! can be lost) and returns it as a `Box<dyn ServoDevice>`.

use super::error::OpenError;
use super::reconnect::Reconnecting;
use super::replay::ReplayDevice;
use super::sim::{HandTargetInput, SimDevice};
use super::spec::DeviceSpec;
use super::ServoDevice;
use crate::mapped::{MappedDevice, SceneMappingSlot};
use glam::DVec3;
use std::time::Duration;
use voxhap_device::drivers::falcon::{Falcon, FalconConfig};
use voxhap_device::drivers::haply::{Haply2Diy, Haply2DiyConfig};
use voxhap_device::drivers::haply_inverse::{HaplyInverse, HaplyInverseConfig};
use voxhap_device::drivers::protocol::{HidLink, ProtocolConfig, ProtocolDevice, SerialLink};
use voxhap_device::drivers::woodenhaptics::{self, WoodenHaptics};
use voxhap_device::drivers::woodenhaptics_serial::{WoodenHapticsSerial, WoodyConfig};
use voxhap_device::profile::{DeviceProfile, Kinematics};
use voxhap_device::sim::SimArmConfig;
use voxhap_device::supervisor::{Supervisor, SupervisorConfig};
use voxhap_device::transport::{HidTransport, SerialTransport};
use voxhap_device::{DeviceError, HapticDevice};

/// An opened device spec: the servo's device, plus the hand-target input when it is the simulated arm.
pub struct OpenedDevice {
    pub device: Box<dyn ServoDevice>,
    pub hand_target: Option<HandTargetInput>,
}

fn boxed<D, F>(config: SupervisorConfig, opener: F) -> Result<Box<dyn ServoDevice>, OpenError>
where
    D: HapticDevice + Send + 'static,
    F: FnMut() -> Result<D, DeviceError> + Send + 'static,
{
    Ok(Box::new(Supervisor::new(config, opener)?))
}

fn reconnecting<D>(
    config: SupervisorConfig,
    opener: impl FnMut() -> Result<D, DeviceError> + Send + 'static,
) -> Result<Box<dyn ServoDevice>, OpenError>
where
    D: HapticDevice + Send + 'static,
{
    Ok(Box::new(Reconnecting::new(config, Box::new(opener))?))
}

fn path_str(path: &std::path::Path) -> Result<String, OpenError> {
    path.to_str()
        .map(str::to_owned)
        .ok_or_else(|| OpenError::Path(path.to_path_buf()))
}

/// Makes the supervised device for `spec`. Nothing is opened yet (call [`ServoDevice::connect`]); the
/// simulated arm uses `sim_arm` (its config and start point) stepped every `period_s`.
pub fn open_device(
    spec: &DeviceSpec,
    config: SupervisorConfig,
    sim_arm: (SimArmConfig, DVec3),
    period_s: f64,
) -> Result<OpenedDevice, OpenError> {
    open_supervised(
        spec,
        config,
        sim_arm,
        period_s,
        &DeviceProfile::default(),
        None,
    )
}

/// [`open_device`] with a device profile: its limits folded into `config`, its kinematics constants into the
/// driver's config, and the device seen through its workspace mapping ([`MappedDevice`]; a fitting mapping
/// fits `volume_bounds_m`, the scene's first volume). The simulated arm's scripted path and start point are
/// scene positions: the arm is given the mapping when the device connects.
pub fn open_device_with_profile(
    spec: &DeviceSpec,
    mut config: SupervisorConfig,
    sim_arm: (SimArmConfig, DVec3),
    period_s: f64,
    profile: &DeviceProfile,
    volume_bounds_m: Option<(DVec3, DVec3)>,
) -> Result<OpenedDevice, OpenError> {
    let family = spec_family(spec);
    if let Some(device) = &profile.device {
        if profile.kinematics != Kinematics::Default && *device != family {
            return Err(OpenError::Profile(format!(
                "device profile {} holds kinematics for {device}, but the device is {family}",
                profile.name
            )));
        }
    }
    profile.apply_to(&mut config);
    let sim_mapping = SceneMappingSlot::default();
    let mut opened = open_supervised(
        spec,
        config,
        sim_arm,
        period_s,
        profile,
        Some(sim_mapping.clone()),
    )?;
    let mapped = MappedDevice::new(opened.device, profile.clone(), volume_bounds_m);
    opened.device = Box::new(mapped.publish_mapping_to(sim_mapping));
    Ok(opened)
}

/// The `--device` kind of a spec (`haply2diy`, `falcon`, ...), as device profiles name it.
pub fn spec_family(spec: &DeviceSpec) -> String {
    let text = spec.to_string();
    let end = text.find([':', ',']).unwrap_or(text.len());
    text[..end].to_owned()
}

fn open_supervised(
    spec: &DeviceSpec,
    config: SupervisorConfig,
    sim_arm: (SimArmConfig, DVec3),
    period_s: f64,
    profile: &DeviceProfile,
    sim_mapping: Option<SceneMappingSlot>,
) -> Result<OpenedDevice, OpenError> {
    let protocol = ProtocolConfig {
        connect_timeout: Duration::from_micros(config.connect_timeout_us),
        ..ProtocolConfig::for_period(Duration::from_secs_f64(period_s))
    };
    // Request/reply drivers wait for a reply at most this long, so a lost one costs at most one tick.
    let period = Duration::from_secs_f64(period_s);
    let reply_wait = voxhap_device::drivers::reply_age::reply_wait(period);
    let mut hand_target = None;
    let device = match spec {
        DeviceSpec::Sim => {
            let local_model = sim_arm.0.local_model;
            let (mut device, input) = SimDevice::new(sim_arm.0, sim_arm.1, period_s)?;
            if let Some(local) = local_model {
                device = device
                    .with_local_model(local.rate_hz)
                    .map_err(|e| OpenError::Profile(e.to_string()))?;
            }
            hand_target = Some(input);
            if let Some(slot) = sim_mapping {
                device.follow_scene_mapping(slot);
            }
            let mut slot = Some(device);
            // The simulated arm cannot be lost, so the opener is called once.
            boxed(config, move || {
                slot.take().ok_or(DeviceError::Config {
                    what: "the simulated arm was already opened".to_owned(),
                })
            })?
        }
        DeviceSpec::Mock(path) | DeviceSpec::Serial(path) => {
            let path = path_str(path)?;
            reconnecting(config, move || {
                let transport = SerialTransport::open(&path, 1_000_000)?;
                Ok(ProtocolDevice::new(SerialLink::new(transport), protocol))
            })?
        }
        DeviceSpec::Hid {
            vendor_id,
            product_id,
            serial,
        } => {
            let (vendor_id, product_id, serial) = (*vendor_id, *product_id, serial.clone());
            reconnecting(config, move || {
                let transport = match &serial {
                    Some(serial) => HidTransport::open_serial(vendor_id, product_id, serial)?,
                    None => HidTransport::open_vid_pid(vendor_id, product_id)?,
                };
                Ok(ProtocolDevice::new(HidLink::new(transport), protocol))
            })?
        }
        DeviceSpec::WoodenHaptics => {
            reconnecting(config, {
                let mut woodenhaptics_config = woodenhaptics::KINEMATICS;
                profile.apply_woodenhaptics_hid(&mut woodenhaptics_config);
                move || {
                    let transport = HidTransport::open_vid_pid(
                        woodenhaptics::VENDOR_ID,
                        woodenhaptics::PRODUCT_ID,
                    )?;
                    Ok(WoodenHaptics::new(transport, woodenhaptics_config)?
                        .with_reply_wait(reply_wait))
                }
            })?
        }
        DeviceSpec::WoodenHapticsSerial(path) => {
            let path = path_str(path)?;
            let mut woody_config = WoodyConfig::for_period(period);
            profile.apply_woodenhaptics(&mut woody_config);
            reconnecting(config, move || {
                // USB CDC-ACM (Teensy) ignores the rate; the firmware calls Serial.begin(115200).
                let transport = SerialTransport::open(&path, 115_200)?;
                Ok(WoodenHapticsSerial::new(transport, woody_config))
            })?
        }
        DeviceSpec::Haply2Diy(path) => {
            let path = path_str(path)?;
            let mut haply_config = Haply2DiyConfig::default();
            profile.apply_haply2diy(&mut haply_config);
            reconnecting(config, move || {
                let transport = SerialTransport::open(&path, 0)?;
                Ok(Haply2Diy::new(transport, haply_config).with_reply_timeout(reply_wait))
            })?
        }
        DeviceSpec::HaplyInverse(url) => {
            let mut driver_config = HaplyInverseConfig::default();
            // `ws://HOST:PORT[,events=ws://HOST:PORT]`, checked when the spec was parsed.
            if let Some(service) =
                voxhap_device::transport::inverse_service::ServiceConfig::from_spec(url)
            {
                driver_config.service = service;
            }
            // `serve --connect-timeout`: the whole connect (TCP, WebSocket upgrade, inventory, session) shares it.
            driver_config.service.connect_timeout =
                Duration::from_micros(config.connect_timeout_us);
            let driver_config = driver_config.for_period(period);
            reconnecting(config, move || Ok(HaplyInverse::new(driver_config.clone())))?
        }
        DeviceSpec::Falcon { select, firmware } => {
            let (select, firmware) = (select.clone(), firmware.clone());
            let mut falcon_config = FalconConfig::for_period(period);
            profile.apply_falcon(&mut falcon_config);
            reconnecting(config, move || {
                let (path, serial) = voxhap_device::discovery::find_falcon(select.as_deref())?;
                let transport =
                    SerialTransport::open(&path, voxhap_device::drivers::falcon::NORMAL_BAUD)?;
                let mut falcon = Falcon::new(
                    transport,
                    FalconConfig {
                        firmware: firmware.clone(),
                        ..falcon_config.clone()
                    },
                );
                if let Some(serial) = serial {
                    falcon.set_serial_number(&serial);
                }
                Ok(falcon)
            })?
        }
        DeviceSpec::Replay { path, options } => {
            let trace = voxhap_record::read_trace(path).map_err(|e| OpenError::Replay {
                path: path.clone(),
                message: e.to_string(),
            })?;
            for warning in &trace.warnings {
                eprintln!("voxhap: warning: {warning}");
            }
            let mut replay =
                ReplayDevice::with_options(&trace, *options).map_err(|e| OpenError::Replay {
                    path: path.clone(),
                    message: e.to_string(),
                })?;
            let name = path.display().to_string();
            eprintln!("voxhap: {}", replay.plan(&name));
            replay
                .report_end(&name)
                .map_err(|e| OpenError::Thread(e.to_string()))?;
            let mut slot = Some(replay);
            boxed(config, move || {
                slot.take().ok_or(DeviceError::Config {
                    what: "the replay device was already opened".to_owned(),
                })
            })?
        }
    };
    Ok(OpenedDevice {
        device,
        hand_target,
    })
}
