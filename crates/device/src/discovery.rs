//! Which devices are plugged in: serial ports (through `serialport`, scanning sysfs, no libudev) and HID devices
//! (through `hidapi`), each matched against the devices voxhap knows, and read-only probes that ask a recognised
//! device who it is.
//!
//! Where it sits: behind `voxhap devices` and the Falcon's opener, before a device is opened. Recognition is by
//! USB vendor and product id where the device has fixed ones (WoodenHaptics 1.5 mbed HID: 1234:0006; Novint
//! Falcon: FTDI 0403:cb48; Teensy USB serial, used by the WoodenHaptics/Polhem Teensy firmware: 16c0:0483;
//! Arduino Due native port, used by the Haply 2DIY: 2341:003d), and by product string for voxhap-protocol
//! firmware (a product name containing "voxhap"). The Haply Inverse3 is not a port of its own: the Haply Inverse
//! Service owns it, and [`probe_inverse_service`] asks the service.

use crate::drivers::woodenhaptics;
use crate::DeviceError;

/// What voxhap thinks a port or HID device is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Recognised {
    /// WoodenHaptics 1.5 firmware (HID).
    WoodenHaptics,
    /// A board that is probably a Haply 2DIY (Arduino Due native USB serial).
    Haply2Diy,
    /// A Novint Falcon (FTDI serial).
    NovintFalcon,
    /// A Teensy USB serial port: probably WoodenHaptics/Polhem on the Teensy firmware.
    Teensy,
    /// Firmware that names itself voxhap (serial or HID).
    VoxhapProtocol,
    /// Not a device voxhap knows.
    Unknown,
}

impl Recognised {
    /// A short description for listings.
    pub fn describe(self) -> &'static str {
        match self {
            Recognised::WoodenHaptics => "WoodenHaptics 1.5, legacy mbed HID firmware",
            Recognised::Haply2Diy => "probably a Haply 2DIY (Arduino Due native port)",
            Recognised::NovintFalcon => "Novint Falcon",
            Recognised::Teensy => "Teensy USB serial: WoodenHaptics/Polhem Teensy firmware?",
            Recognised::VoxhapProtocol => "voxhap protocol firmware",
            Recognised::Unknown => "not recognised",
        }
    }
}

/// Matches a USB identity.
pub fn recognise_usb(vendor_id: u16, product_id: u16, product: Option<&str>) -> Recognised {
    if product.is_some_and(|name| name.to_ascii_lowercase().contains("voxhap")) {
        return Recognised::VoxhapProtocol;
    }
    match (vendor_id, product_id) {
        (woodenhaptics::VENDOR_ID, woodenhaptics::PRODUCT_ID) => Recognised::WoodenHaptics,
        (0x0403, 0xcb48) => Recognised::NovintFalcon,
        (0x2341, 0x003d) => Recognised::Haply2Diy,
        (0x16c0, 0x0483) => Recognised::Teensy,
        _ => Recognised::Unknown,
    }
}

/// One serial port.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SerialPortEntry {
    /// Device path.
    pub path: String,
    /// USB vendor and product id, for USB ports.
    pub usb_id: Option<(u16, u16)>,
    /// USB product string, where known.
    pub product: Option<String>,
    /// USB manufacturer string, where known.
    pub manufacturer: Option<String>,
    /// USB serial number, where known.
    pub serial_number: Option<String>,
    /// What it is.
    pub recognised: Recognised,
}

/// One HID device.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HidEntry {
    /// hidraw path.
    pub path: String,
    /// USB vendor id.
    pub vendor_id: u16,
    /// USB product id.
    pub product_id: u16,
    /// Product string.
    pub product: Option<String>,
    /// Manufacturer string.
    pub manufacturer: Option<String>,
    /// Serial number string.
    pub serial_number: Option<String>,
    /// What it is.
    pub recognised: Recognised,
}

/// Lists serial ports. An enumeration failure is returned as its message.
pub fn serial_ports() -> Result<Vec<SerialPortEntry>, String> {
    let ports = serialport::available_ports().map_err(|error| error.to_string())?;
    Ok(ports
        .into_iter()
        .map(|port| match port.port_type {
            serialport::SerialPortType::UsbPort(usb) => SerialPortEntry {
                recognised: recognise_usb(usb.vid, usb.pid, usb.product.as_deref()),
                path: port.port_name,
                usb_id: Some((usb.vid, usb.pid)),
                product: usb.product,
                manufacturer: usb.manufacturer,
                serial_number: usb.serial_number,
            },
            _ => SerialPortEntry {
                path: port.port_name,
                usb_id: None,
                product: None,
                manufacturer: None,
                serial_number: None,
                recognised: Recognised::Unknown,
            },
        })
        .collect())
}

/// The Falcon to open for `falcon[:SELECT]`: SELECT is a port path (starting with `/`) or a USB serial number;
/// without it, the first Falcon (USB 0403:cb48) among the serial ports. Returns the path and, when known, the
/// USB serial number.
pub fn find_falcon(select: Option<&str>) -> Result<(String, Option<String>), DeviceError> {
    if let Some(path) = select.filter(|s| s.starts_with('/')) {
        return Ok((path.to_owned(), None));
    }
    let ports = serial_ports().map_err(|message| DeviceError::Open {
        path: "Novint Falcon".to_owned(),
        message: format!("cannot list serial ports: {message}"),
    })?;
    ports
        .into_iter()
        .find(|port| {
            port.recognised == Recognised::NovintFalcon
                && select.is_none_or(|serial| port.serial_number.as_deref() == Some(serial))
        })
        .map(|port| (port.path, port.serial_number))
        .ok_or_else(|| DeviceError::Open {
            path: match select {
                Some(serial) => format!("Novint Falcon with serial {serial}"),
                None => "Novint Falcon".to_owned(),
            },
            message: "no serial port with USB id 0403:cb48: is it plugged in and powered, and does ftdi_sio \
                      know its id? (install contrib/udev/70-voxhap.rules; `voxhap devices` lists what is \
                      connected; docs/devices/novint-falcon.md)"
                .to_owned(),
        })
}

/// Lists HID devices. A failure to start hidapi is returned as its message.
pub fn hid_devices() -> Result<Vec<HidEntry>, String> {
    let api = hidapi::HidApi::new().map_err(|error| error.to_string())?;
    Ok(api
        .device_list()
        .map(|device| HidEntry {
            path: device.path().to_string_lossy().into_owned(),
            vendor_id: device.vendor_id(),
            product_id: device.product_id(),
            product: device.product_string().map(str::to_string),
            manufacturer: device.manufacturer_string().map(str::to_string),
            serial_number: device.serial_number().map(str::to_string),
            recognised: recognise_usb(
                device.vendor_id(),
                device.product_id(),
                device.product_string(),
            ),
        })
        .collect())
}

/// What a device said about itself when probed.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ProbeReport {
    /// Model, as the device reports it.
    pub model: Option<String>,
    /// Serial number or device id.
    pub serial_number: Option<String>,
    /// Firmware version.
    pub firmware: Option<String>,
    /// What the probe sent, for the operator (empty when it only listened).
    pub sent: &'static str,
}

/// Probes a serial port voxhap recognised. Only devices that answer without being driven are probed:
/// voxhap-protocol firmware (Hello, then one zero force; the device is not enabled) and the WoodenHaptics
/// Teensy firmware (one zero-current command: it answers only commands; its 100 ms watchdog then cuts the
/// amplifiers). `Ok(None)` for devices that are not probed (the Haply 2DIY answers only motor commands, the
/// Falcon's firmware may need uploading).
pub fn probe_serial(entry: &SerialPortEntry) -> Result<Option<ProbeReport>, DeviceError> {
    use crate::drivers::woodenhaptics_serial::{WoodenHapticsSerial, WoodyConfig};
    use crate::drivers::{ProtocolConfig, ProtocolDevice, SerialLink};
    use crate::transport::SerialTransport;
    use crate::HapticDevice;
    use std::time::Duration;
    match entry.recognised {
        Recognised::VoxhapProtocol => {
            let transport = SerialTransport::open(&entry.path, 1_000_000)?;
            // A probe of every port keeps the old half second per port (SPEC section 7.1's first Hellos).
            let config = ProtocolConfig {
                connect_timeout: Duration::from_millis(500),
                ..ProtocolConfig::default()
            };
            let mut device = ProtocolDevice::new(SerialLink::new(transport), config);
            device.open()?;
            let info = device.info().clone();
            let _ = device.close();
            Ok(Some(ProbeReport {
                model: Some(info.model),
                serial_number: Some(info.serial_number).filter(|s| !s.is_empty()),
                firmware: None,
                sent: "Hello and one zero force (not enabled)",
            }))
        }
        Recognised::Teensy => {
            let transport = SerialTransport::open(&entry.path, 115_200)?;
            let config = WoodyConfig {
                hello_attempts: 2,
                hello_timeout: Duration::from_millis(50),
                ..WoodyConfig::default()
            };
            let mut device = WoodenHapticsSerial::new(transport, config);
            device.open()?;
            let model = device.model().map(|m| m.name().to_owned());
            let _ = device.close();
            Ok(Some(ProbeReport {
                model,
                serial_number: entry.serial_number.clone(),
                firmware: None,
                sent: "one zero-current command [0,0,0]",
            }))
        }
        _ => Ok(None),
    }
}

/// Asks the Haply Inverse Service at `url` which Inverse3 devices it has (reads its inventory message only).
pub fn probe_inverse_service(
    url: &str,
) -> Result<Vec<crate::transport::inverse_service::ServiceDevice>, DeviceError> {
    crate::transport::inverse_service::inventory(url, std::time::Duration::from_millis(500))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recognises_known_usb_ids_and_voxhap_product_names() {
        assert_eq!(
            recognise_usb(0x1234, 0x0006, None),
            Recognised::WoodenHaptics
        );
        assert_eq!(
            recognise_usb(0x0403, 0xcb48, None),
            Recognised::NovintFalcon
        );
        assert_eq!(recognise_usb(0x2341, 0x003d, None), Recognised::Haply2Diy);
        assert_eq!(recognise_usb(0x16c0, 0x0483, None), Recognised::Teensy);
        assert_eq!(
            recognise_usb(0x1209, 0x0001, Some("Voxhap arm")),
            Recognised::VoxhapProtocol
        );
        assert_eq!(
            recognise_usb(0x1209, 0x0001, Some("keyboard")),
            Recognised::Unknown
        );
    }
}
