//! Which devices are plugged in: serial ports (through `serialport`, scanning sysfs, no libudev) and HID devices
//! (through `hidapi`), each matched against the devices voxhap knows.
//!
//! Where it sits: behind `voxhap devices`, before a device is opened. Recognition is by USB vendor and product id
//! where the device has fixed ones (WoodenHaptics 1.5: 1234:0006; Novint Falcon: FTDI 0403:cb48; Arduino Due
//! native port, used by the Haply 2DIY: 2341:003d), by product string for voxhap-protocol firmware (a product
//! name containing "voxhap"), and by path for voxhap's own mock device (a pseudo-terminal).

use crate::device::drivers::woodenhaptics;

/// What voxhap thinks a port or HID device is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Recognised {
    /// WoodenHaptics 1.5 firmware (HID).
    WoodenHaptics,
    /// A board that is probably a Haply 2DIY (Arduino Due native USB serial).
    Haply2Diy,
    /// A Novint Falcon (FTDI serial; not supported by a driver yet).
    NovintFalcon,
    /// Firmware that names itself voxhap (serial or HID).
    VoxhapProtocol,
    /// Not a device voxhap knows.
    Unknown,
}

impl Recognised {
    /// A short description for listings.
    pub fn describe(self) -> &'static str {
        match self {
            Recognised::WoodenHaptics => "WoodenHaptics 1.5 (driver: woodenhaptics)",
            Recognised::Haply2Diy => {
                "probably a Haply 2DIY (Arduino Due native port; driver: haply-2diy)"
            }
            Recognised::NovintFalcon => "Novint Falcon (no driver yet)",
            Recognised::VoxhapProtocol => {
                "voxhap protocol firmware (driver: voxhap-serial / voxhap-hid)"
            }
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
            },
            _ => SerialPortEntry {
                path: port.port_name,
                usb_id: None,
                product: None,
                recognised: Recognised::Unknown,
            },
        })
        .collect())
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
            recognised: recognise_usb(
                device.vendor_id(),
                device.product_id(),
                device.product_string(),
            ),
        })
        .collect())
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
