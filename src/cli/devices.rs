//! `voxhap devices`: lists serial ports, HID devices and the Haply Inverse Service's arms, names the ones voxhap
//! recognises with the `--device` value that drives them, and probes each recognised device that can answer
//! without being driven (model, serial number, firmware) (crates/device/src/discovery.rs). `--json` prints the same
//! as one JSON document for scripts.

use crate::device::discovery::{
    hid_devices, probe_inverse_service, probe_serial, serial_ports, ProbeReport, Recognised,
};
use crate::device::transport::inverse_service::DEFAULT_URL;
use clap::Args;
use serde::Serialize;

/// Arguments of `voxhap devices`.
#[derive(Debug, Args)]
pub struct DevicesArgs {
    /// Also list devices voxhap does not recognise.
    #[arg(long)]
    pub all: bool,
    /// Print one JSON document instead of text.
    #[arg(long)]
    pub json: bool,
    /// Do not probe recognised devices (list USB descriptors only; nothing is sent to any device).
    #[arg(long)]
    pub no_probe: bool,
    /// Where to ask the Haply Inverse Service for Inverse3 arms.
    #[arg(long, default_value = DEFAULT_URL)]
    pub inverse_service: String,
}

/// One listed device.
#[derive(Debug, Serialize)]
struct Listed {
    bus: &'static str,
    path: String,
    usb_id: Option<String>,
    product: Option<String>,
    manufacturer: Option<String>,
    serial_number: Option<String>,
    recognised: Option<&'static str>,
    /// The `--device` value that drives it.
    device: Option<String>,
    probe: Option<Probe>,
}

#[derive(Debug, Serialize)]
struct Probe {
    model: Option<String>,
    serial_number: Option<String>,
    firmware: Option<String>,
    sent: &'static str,
    error: Option<String>,
}

impl From<ProbeReport> for Probe {
    fn from(report: ProbeReport) -> Probe {
        Probe {
            model: report.model,
            serial_number: report.serial_number,
            firmware: report.firmware,
            sent: report.sent,
            error: None,
        }
    }
}

/// A bus that could not be listed ("serial", "hid", "inverse-service").
#[derive(Debug, Serialize)]
struct BusError {
    bus: &'static str,
    message: String,
}

/// The whole listing.
#[derive(Debug, Serialize)]
struct Listing {
    devices: Vec<Listed>,
    /// Per-bus enumeration failures.
    errors: Vec<BusError>,
    /// Devices seen in all, recognised or not.
    seen: usize,
}

impl Listing {
    /// What `bus` listed, each counted as seen; a bus that could not be listed is recorded in `errors` and
    /// lists nothing.
    fn take_bus<T>(&mut self, bus: &'static str, listed: Result<Vec<T>, impl ToString>) -> Vec<T> {
        match listed {
            Ok(found) => {
                self.seen += found.len();
                found
            }
            Err(error) => {
                self.errors.push(BusError {
                    bus,
                    message: error.to_string(),
                });
                Vec::new()
            }
        }
    }
}

fn device_value(recognised: Recognised, path: &str, serial: Option<&str>) -> Option<String> {
    match recognised {
        Recognised::WoodenHaptics => Some("woodenhaptics-hid".to_owned()),
        Recognised::Teensy => Some(format!("woodenhaptics:{path}")),
        Recognised::Haply2Diy => Some(format!("haply2diy:{path}")),
        Recognised::NovintFalcon => Some(match serial {
            Some(serial) => format!("falcon:{serial},firmware=FILE"),
            None => format!("falcon:{path},firmware=FILE"),
        }),
        Recognised::VoxhapProtocol => Some(format!("serial:{path}")),
        Recognised::Unknown => None,
    }
}

fn collect(args: &DevicesArgs) -> Listing {
    let mut listing = Listing {
        devices: Vec::new(),
        errors: Vec::new(),
        seen: 0,
    };
    for port in listing.take_bus("serial", serial_ports()) {
        let known = port.recognised != Recognised::Unknown;
        if !known && !args.all {
            continue;
        }
        let probe = if known && !args.no_probe {
            match probe_serial(&port) {
                Ok(report) => report.map(Probe::from),
                Err(error) => Some(Probe {
                    model: None,
                    serial_number: None,
                    firmware: None,
                    sent: "",
                    error: Some(error.to_string()),
                }),
            }
        } else {
            None
        };
        listing.devices.push(Listed {
            bus: "serial",
            device: device_value(port.recognised, &port.path, port.serial_number.as_deref()),
            usb_id: port.usb_id.map(|(v, p)| format!("{v:04x}:{p:04x}")),
            recognised: known.then(|| port.recognised.describe()),
            path: port.path,
            product: port.product,
            manufacturer: port.manufacturer,
            serial_number: port.serial_number,
            probe,
        });
    }
    for device in listing.take_bus("hid", hid_devices()) {
        let known = device.recognised != Recognised::Unknown;
        if !known && !args.all {
            continue;
        }
        listing.devices.push(Listed {
            bus: "hid",
            device: match device.recognised {
                Recognised::VoxhapProtocol => Some(format!(
                    "hid:{:04x}:{:04x}",
                    device.vendor_id, device.product_id
                )),
                other => device_value(other, &device.path, None),
            },
            usb_id: Some(format!(
                "{:04x}:{:04x}",
                device.vendor_id, device.product_id
            )),
            recognised: known.then(|| device.recognised.describe()),
            path: device.path,
            product: device.product,
            manufacturer: device.manufacturer,
            serial_number: device.serial_number,
            probe: None,
        });
    }
    if !args.no_probe {
        for arm in listing.take_bus(
            "inverse-service",
            probe_inverse_service(&args.inverse_service),
        ) {
            listing.devices.push(Listed {
                bus: "inverse-service",
                path: format!("{} device {}", args.inverse_service, arm.device_id),
                usb_id: None,
                product: Some(arm.device_type.clone()),
                manufacturer: Some("Haply".to_owned()),
                serial_number: Some(arm.device_id.clone()),
                recognised: Some("Haply Inverse3 family, through the Inverse Service"),
                device: Some(format!("haply-inverse:{}", args.inverse_service)),
                probe: Some(Probe {
                    model: Some(arm.device_type),
                    serial_number: Some(arm.device_id),
                    firmware: arm.firmware,
                    sent: "nothing (read the service's inventory)",
                    error: None,
                }),
            });
        }
    }
    listing
}

fn text(listing: &Listing, args: &DevicesArgs) -> String {
    let mut lines = Vec::new();
    if listing.devices.is_empty() {
        lines.push(if args.all || listing.seen == 0 {
            format!("No devices found ({} seen).", listing.seen)
        } else {
            format!(
                "No recognised devices ({} seen; --all lists them).",
                listing.seen
            )
        });
    }
    for d in &listing.devices {
        let mut line = format!("{} {}", d.bus, d.path);
        if let Some(id) = &d.usb_id {
            line += &format!(" [{id}]");
        }
        if let Some(product) = &d.product {
            line += &format!(" \"{product}\"");
        }
        if let Some(serial) = &d.serial_number {
            line += &format!(" serial {serial}");
        }
        line += &format!(": {}", d.recognised.unwrap_or("not recognised"));
        lines.push(line);
        if let Some(probe) = &d.probe {
            match &probe.error {
                Some(error) => lines.push(format!("    probe failed: {error}")),
                None => {
                    let field = |name: &str, v: &Option<String>| {
                        v.as_ref()
                            .map(|v| format!(" {name} {v}"))
                            .unwrap_or_default()
                    };
                    lines.push(format!(
                        "    reports:{}{}{} (probe sent: {})",
                        field("model", &probe.model),
                        field("serial", &probe.serial_number),
                        field("firmware", &probe.firmware),
                        probe.sent
                    ));
                }
            }
        }
        if let Some(device) = &d.device {
            lines.push(format!("    voxhap serve --device {device}"));
        }
    }
    for error in &listing.errors {
        if error.bus == "inverse-service" {
            lines.push(format!(
                "Haply Inverse Service not reached ({})",
                error.message
            ));
        } else {
            lines.push(format!(
                "cannot list {} devices: {}",
                error.bus, error.message
            ));
        }
    }
    lines.join("\n")
}

/// Prints the listing. Enumeration failures are reported per bus, not fatal.
pub fn run(args: &DevicesArgs) -> anyhow::Result<()> {
    let listing = collect(args);
    if args.json {
        super::common::print_out(&serde_json::to_string_pretty(&listing)?)
    } else {
        super::common::print_out(&text(&listing, args))
    }
}
