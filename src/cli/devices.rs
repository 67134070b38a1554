//! `voxhap devices`: lists serial ports and HID devices and names the ones voxhap recognises
//! (src/device/discovery.rs).

use crate::device::discovery::{hid_devices, serial_ports, Recognised};
use clap::Args;

/// Arguments of `voxhap devices`.
#[derive(Debug, Args)]
pub struct DevicesArgs {
    /// Also list devices voxhap does not recognise.
    #[arg(long)]
    pub all: bool,
}

/// Prints the listing. Enumeration failures are reported per bus, not fatal.
pub fn run(args: &DevicesArgs) -> anyhow::Result<()> {
    let mut lines = Vec::new();
    lines.push("Serial ports:".to_string());
    match serial_ports() {
        Err(error) => lines.push(format!("  (cannot list serial ports: {error})")),
        Ok(ports) => {
            let shown: Vec<_> = ports
                .iter()
                .filter(|port| args.all || port.recognised != Recognised::Unknown)
                .collect();
            if shown.is_empty() {
                lines.push(format!(
                    "  none recognised ({} ports in all; --all lists them)",
                    ports.len()
                ));
            }
            for port in shown {
                let usb = port
                    .usb_id
                    .map(|(vid, pid)| format!(" [{vid:04x}:{pid:04x}]"))
                    .unwrap_or_default();
                let product = port
                    .product
                    .as_deref()
                    .map(|p| format!(" \"{p}\""))
                    .unwrap_or_default();
                lines.push(format!(
                    "  {}{usb}{product}: {}",
                    port.path,
                    port.recognised.describe()
                ));
            }
        }
    }
    lines.push("HID devices:".to_string());
    match hid_devices() {
        Err(error) => lines.push(format!("  (cannot list HID devices: {error})")),
        Ok(devices) => {
            let shown: Vec<_> = devices
                .iter()
                .filter(|device| args.all || device.recognised != Recognised::Unknown)
                .collect();
            if shown.is_empty() {
                lines.push(format!(
                    "  none recognised ({} devices in all; --all lists them)",
                    devices.len()
                ));
            }
            for device in shown {
                let product = device.product.as_deref().unwrap_or("?");
                lines.push(format!(
                    "  {} [{:04x}:{:04x}] \"{product}\": {}",
                    device.path,
                    device.vendor_id,
                    device.product_id,
                    device.recognised.describe()
                ));
            }
        }
    }
    super::print_out(&lines.join("\n"))
}
