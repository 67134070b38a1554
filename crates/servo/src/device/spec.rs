//! Device-spec parsing: the `--device` argument ([`DeviceSpec`]), parsed from and printed back to text.
//! Nothing is opened here (see `factory`).

use std::path::PathBuf;
use std::str::FromStr;

/// Which device to drive: the `--device` argument.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum DeviceSpec {
    /// `sim`: the in-process simulated arm.
    Sim,
    /// `mock:PATH`: `voxhap mock-device` on the pseudo-terminal at PATH (voxhap protocol over serial).
    Mock(PathBuf),
    /// `serial:PATH`: a device speaking the voxhap protocol on the serial port at PATH.
    Serial(PathBuf),
    /// `hid:VID:PID[:SERIAL]`: a device speaking the voxhap protocol over USB HID (hex ids).
    Hid {
        vendor_id: u16,
        product_id: u16,
        serial: Option<String>,
    },
    /// `woodenhaptics-hid`: WoodenHaptics 1.5 over USB HID (legacy mbed firmware).
    WoodenHaptics,
    /// `woodenhaptics:PATH`: WoodenHaptics, Polhem or a retrofitted PHANTOM on the Teensy firmware (USB serial);
    /// the model comes from the device's reports.
    WoodenHapticsSerial(PathBuf),
    /// `haply2diy:PATH`: Haply 2DIY on the USB serial port at PATH.
    Haply2Diy(PathBuf),
    /// `replay:TRACE[,seek=S][,speed=X][,loop]`: plays the probe positions of a recorded trace, once
    /// (then holds the last position) unless `loop` is given.
    Replay {
        /// The trace file.
        path: PathBuf,
        /// Seek, speed and loop.
        options: super::replay::ReplayOptions,
    },
    /// `haply-inverse[:ws://HOST:PORT[,events=ws://HOST:PORT]]`: Haply Inverse3 through the Haply Inverse Service
    /// (the events channel defaults to the same host's port 10020).
    HaplyInverse(String),
    /// `falcon[:SERIAL|:PATH][,firmware=FILE]`: Novint Falcon on its FTDI serial port (`ftdi_sio`), chosen by
    /// USB serial number or port path (default: the first Falcon found); FILE is Novint's firmware, uploaded
    /// when none is running.
    Falcon {
        select: Option<String>,
        firmware: Option<PathBuf>,
    },
}

/// Why `--device` was not understood.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("--device {given:?}: {problem}; expected sim, mock:PATH, serial:PATH, hid:VID:PID[:SERIAL], woodenhaptics:PATH, woodenhaptics-hid, haply2diy:PATH, haply-inverse[:ws://HOST:PORT[,events=ws://HOST:PORT]], falcon[:SERIAL|:PATH][,firmware=FILE] or replay:TRACE[,seek=S][,speed=X][,loop]")]
pub struct DeviceSpecError {
    /// The `--device` text as given.
    pub given: String,
    /// What is wrong with it.
    pub problem: DeviceSpecProblem,
}

/// What is wrong with a `--device` text.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DeviceSpecProblem {
    /// `KIND:` with nothing after the colon.
    #[error("a path is needed after the colon")]
    NoPath,
    /// `woodenhaptics` without a port.
    #[error(
        "needs the serial port of the Teensy firmware, e.g. woodenhaptics:/dev/ttyACM0 \
         (the retired mbed HID firmware is woodenhaptics-hid)"
    )]
    WoodenHapticsNeedsPort,
    /// A replay spec that does not parse.
    #[error(transparent)]
    Replay(#[from] super::replay::ReplaySpecError),
    /// `haply-inverse:` followed by something that is not `ws://HOST:PORT[,events=ws://HOST:PORT]`.
    #[error("the Inverse Service address must be ws://HOST:PORT, optionally followed by ,events=ws://HOST:PORT for its events channel (default ws://127.0.0.1:10001, events on the same host's port 10020)")]
    InverseUrl,
    /// `hid` without ids.
    #[error("hid needs VID:PID")]
    HidNeedsIds,
    /// A vendor or product id that is not a 16-bit hex number.
    #[error("{what} {part:?} is not a 16-bit hex number")]
    HexId {
        /// `vendor id` or `product id`.
        what: &'static str,
        /// The text given.
        part: String,
    },
    /// An argument after a kind that takes none.
    #[error("takes no argument")]
    TakesNoArgument,
    /// The kind before the colon is unknown.
    #[error("unknown device kind")]
    UnknownKind,
    /// A falcon option other than `firmware=FILE`.
    #[error("unknown falcon option {0:?} (the only one is firmware=FILE)")]
    FalconOption(String),
}

impl FromStr for DeviceSpec {
    type Err = DeviceSpecError;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let error = |problem: DeviceSpecProblem| DeviceSpecError {
            given: text.to_owned(),
            problem,
        };
        if let Some(rest) = text.strip_prefix("falcon") {
            if rest.is_empty() || rest.starts_with(':') || rest.starts_with(',') {
                return parse_falcon(rest).map_err(error);
            }
        }
        let (kind, rest) = match text.split_once(':') {
            Some((kind, rest)) => (kind, Some(rest)),
            None => (text, None),
        };
        let path = |rest: Option<&str>| match rest {
            Some(p) if !p.is_empty() => Ok(PathBuf::from(p)),
            _ => Err(error(DeviceSpecProblem::NoPath)),
        };
        match kind {
            "sim" if rest.is_none() => Ok(DeviceSpec::Sim),
            "woodenhaptics-hid" if rest.is_none() => Ok(DeviceSpec::WoodenHaptics),
            "woodenhaptics" if rest.is_none() => {
                Err(error(DeviceSpecProblem::WoodenHapticsNeedsPort))
            }
            "woodenhaptics" => Ok(DeviceSpec::WoodenHapticsSerial(path(rest)?)),
            "mock" => Ok(DeviceSpec::Mock(path(rest)?)),
            "serial" => Ok(DeviceSpec::Serial(path(rest)?)),
            "haply2diy" => Ok(DeviceSpec::Haply2Diy(path(rest)?)),
            "replay" => {
                let (path, options) = super::replay::parse_replay_spec(rest.unwrap_or(""))
                    .map_err(|problem| error(problem.into()))?;
                Ok(DeviceSpec::Replay { path, options })
            }
            "haply-inverse" => match rest {
                None => Ok(DeviceSpec::HaplyInverse(
                    voxhap_device::transport::inverse_service::DEFAULT_URL.to_owned(),
                )),
                Some(url)
                    if voxhap_device::transport::inverse_service::ServiceConfig::from_spec(url)
                        .is_some() =>
                {
                    Ok(DeviceSpec::HaplyInverse(url.to_owned()))
                }
                Some(_) => Err(error(DeviceSpecProblem::InverseUrl)),
            },
            "hid" => {
                let rest = rest.ok_or_else(|| error(DeviceSpecProblem::HidNeedsIds))?;
                let mut parts = rest.splitn(3, ':');
                let mut id = |what: &'static str| {
                    let part = parts.next().unwrap_or("");
                    let digits = part.trim_start_matches("0x");
                    u16::from_str_radix(digits, 16).map_err(|_| {
                        error(DeviceSpecProblem::HexId {
                            what,
                            part: part.to_owned(),
                        })
                    })
                };
                let vendor_id = id("vendor id")?;
                let product_id = id("product id")?;
                let serial = parts.next().filter(|s| !s.is_empty()).map(str::to_owned);
                Ok(DeviceSpec::Hid {
                    vendor_id,
                    product_id,
                    serial,
                })
            }
            "sim" | "woodenhaptics-hid" => Err(error(DeviceSpecProblem::TakesNoArgument)),
            _ => Err(error(DeviceSpecProblem::UnknownKind)),
        }
    }
}

/// The part of a `falcon` spec after the word: `[:SERIAL|:PATH][,firmware=FILE]`.
fn parse_falcon(rest: &str) -> Result<DeviceSpec, DeviceSpecProblem> {
    let rest = rest.strip_prefix(':').unwrap_or(rest);
    let mut parts = rest.split(',');
    let select = parts.next().filter(|s| !s.is_empty()).map(str::to_owned);
    let mut firmware = None;
    for option in parts {
        match option.split_once('=') {
            Some(("firmware", path)) if !path.is_empty() => firmware = Some(PathBuf::from(path)),
            _ => return Err(DeviceSpecProblem::FalconOption(option.to_owned())),
        }
    }
    Ok(DeviceSpec::Falcon { select, firmware })
}

impl std::fmt::Display for DeviceSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            DeviceSpec::Sim => f.write_str("sim"),
            DeviceSpec::Mock(p) => write!(f, "mock:{}", p.display()),
            DeviceSpec::Serial(p) => write!(f, "serial:{}", p.display()),
            DeviceSpec::Hid {
                vendor_id,
                product_id,
                serial,
            } => {
                write!(f, "hid:{vendor_id:04x}:{product_id:04x}")?;
                match serial {
                    Some(s) => write!(f, ":{s}"),
                    None => Ok(()),
                }
            }
            DeviceSpec::WoodenHaptics => f.write_str("woodenhaptics-hid"),
            DeviceSpec::WoodenHapticsSerial(p) => write!(f, "woodenhaptics:{}", p.display()),
            DeviceSpec::Haply2Diy(p) => write!(f, "haply2diy:{}", p.display()),
            DeviceSpec::Replay { path, options } => {
                write!(f, "replay:{}", path.display())?;
                let defaults = super::replay::ReplayOptions::default();
                if options.seek_s != defaults.seek_s {
                    write!(f, ",seek={}", options.seek_s)?;
                }
                if options.speed != defaults.speed {
                    write!(f, ",speed={}", options.speed)?;
                }
                if options.looped {
                    f.write_str(",loop")?;
                }
                Ok(())
            }
            DeviceSpec::HaplyInverse(url) => write!(f, "haply-inverse:{url}"),
            DeviceSpec::Falcon { select, firmware } => {
                f.write_str("falcon")?;
                if let Some(select) = select {
                    write!(f, ":{select}")?;
                }
                match firmware {
                    Some(path) => write!(f, ",firmware={}", path.display()),
                    None => Ok(()),
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_replay_options_are_refused_by_name() {
        for (text, expected) in [
            ("replay:t.csv,speed=0", "replay speed 0 must be > 0"),
            (
                "replay:t.csv,speed=fast",
                "replay speed=\"fast\": not a finite number",
            ),
            ("replay:t.csv,seek=-1", "replay seek -1 s must be >= 0"),
            ("replay:t.csv,seek=inf", "not a finite number"),
            (
                "replay:t.csv,repeat",
                "replay option \"repeat\": expected seek=S, speed=X or loop",
            ),
            ("replay:", "replay: needs a trace file"),
        ] {
            let error = text.parse::<DeviceSpec>().unwrap_err().to_string();
            assert!(error.contains(expected), "{text}: {error}");
        }
        let spec: DeviceSpec = "replay:t.csv,loop,speed=2.5,seek=3".parse().unwrap();
        let DeviceSpec::Replay { path, options } = spec else {
            panic!("not a replay: {spec:?}");
        };
        assert_eq!(path, PathBuf::from("t.csv"));
        assert_eq!(
            (options.seek_s, options.speed, options.looped),
            (3.0, 2.5, true)
        );
    }

    #[test]
    fn device_specs_parse_and_print_back() {
        for text in [
            "sim",
            "mock:/dev/pts/3",
            "serial:/dev/ttyACM0",
            "hid:1234:0006",
            "hid:1234:0006:SN-1",
            "woodenhaptics-hid",
            "woodenhaptics:/dev/ttyACM2",
            "haply2diy:/dev/ttyACM1",
            "replay:trace.csv",
            "replay:trace.parquet,seek=1.5,speed=2,loop",
            "replay:trace.csv,speed=0.5",
            "haply-inverse:ws://127.0.0.1:10001",
            "haply-inverse:ws://lab-pc:9000",
            "haply-inverse:ws://lab-pc:9000,events=ws://lab-pc:9020",
            "falcon",
            "falcon:A1B2C3",
            "falcon:/dev/ttyUSB0,firmware=/opt/novint/test_firmware.bin",
            "falcon,firmware=fw.bin",
        ] {
            let spec: DeviceSpec = text.parse().unwrap();
            assert_eq!(spec.to_string(), text);
        }
        assert_eq!(
            "hid:0x1234:6".parse::<DeviceSpec>().unwrap(),
            DeviceSpec::Hid {
                vendor_id: 0x1234,
                product_id: 6,
                serial: None
            }
        );
    }

    #[test]
    fn bad_device_specs_say_what_is_wrong() {
        for (text, problem) in [
            ("falconx", "unknown device kind"),
            ("falcon:SN,speed=3", "unknown falcon option"),
            ("mock:", "a path is needed"),
            ("serial", "a path is needed"),
            ("sim:x", "takes no argument"),
            ("hid:zz:0001", "vendor id \"zz\""),
            ("hid:1234", "product id \"\""),
            ("haply-inverse:localhost:10001", "must be ws://HOST:PORT"),
            ("haply-inverse:ws://h:1,events=h:2", "events=ws://HOST:PORT"),
            ("haply-inverse:ws://h:1,events=", "events=ws://HOST:PORT"),
            ("woodenhaptics", "woodenhaptics-hid"),
        ] {
            let err = text.parse::<DeviceSpec>().unwrap_err().to_string();
            assert!(err.contains(problem), "{text}: {err}");
            assert!(err.contains("expected sim"), "{err}");
        }
    }
}
