//! Bring-up that explains itself: open errors carry the OS reason and the next step, and `voxhap devices`
//! (text and `--json`) reports what it finds, here the arms of an Inverse Service double on 127.0.0.1.

use crate::util::inverse_service::{InverseService, DEVICE_ID};
use std::process::Command;
use voxhap::device::transport::SerialTransport;

#[test]
fn a_missing_port_says_so_and_points_at_voxhap_devices() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("ttyACM9");
    let message = SerialTransport::open(path.to_str().unwrap(), 115_200)
        .unwrap_err()
        .to_string();
    assert!(message.contains("No such file or directory"), "{message}");
    assert!(
        message.contains("`voxhap devices` lists what is connected"),
        "{message}"
    );
}

#[test]
fn a_port_without_permission_names_the_dialout_group_and_the_udev_rules() {
    // A pseudo-terminal whose mode we drop to 000: opening it is refused for a normal user.
    let pty = crate::util::pty::PtyDevice::new();
    let path = pty.path().to_string();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o000)).unwrap();
    match SerialTransport::open(&path, 115_200) {
        Ok(_) => eprintln!(
            "SKIPPED: running as root, so a mode-000 device opens anyway; the permission message is not checked here"
        ),
        Err(error) => {
            let message = error.to_string();
            assert!(message.contains("Permission denied"), "{message}");
            assert!(message.contains("dialout"), "{message}");
            assert!(message.contains("contrib/udev/70-voxhap.rules"), "{message}");
        }
    }
}

#[test]
fn voxhap_devices_lists_the_inverse_services_arms_as_text_and_json() {
    let service = InverseService::start();
    let run = |json: bool| {
        let mut command = Command::new(env!("CARGO_BIN_EXE_voxhap"));
        command.args(["devices", "--inverse-service", &service.url()]);
        if json {
            command.arg("--json");
        }
        let output = command.output().unwrap();
        assert!(output.status.success(), "{output:?}");
        String::from_utf8(output.stdout).unwrap()
    };
    let text = run(false);
    assert!(text.contains(&format!("serial {DEVICE_ID}")), "{text}");
    assert!(text.contains("firmware 7.4"), "{text}");
    assert!(
        text.contains(&format!(
            "voxhap serve --device haply-inverse:{}",
            service.url()
        )),
        "{text}"
    );
    let json: serde_json::Value = serde_json::from_str(&run(true)).unwrap();
    let arm = json["devices"]
        .as_array()
        .unwrap()
        .iter()
        .find(|d| d["bus"] == "inverse-service")
        .expect("the arm is listed");
    assert_eq!(arm["probe"]["serial_number"], DEVICE_ID);
    assert_eq!(arm["probe"]["firmware"], "7.4");
    assert_eq!(arm["probe"]["model"], "inverse3");
    // Reading the inventory sends no command: the service logged no force.
    assert!(service.forces().is_empty(), "{:?}", service.events());
}

#[test]
fn with_all_the_listing_does_not_suggest_all() {
    let output = Command::new(env!("CARGO_BIN_EXE_voxhap"))
        .args(["devices", "--all", "--no-probe"])
        .output()
        .unwrap();
    let text = String::from_utf8(output.stdout).unwrap();
    assert!(!text.contains("--all lists them"), "{text}");
}

#[test]
fn the_udev_rules_cover_every_usb_id_voxhap_recognises() {
    use voxhap::device::discovery::{recognise_usb, Recognised};
    let rules = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/contrib/udev/70-voxhap.rules"
    ))
    .unwrap();
    for (vid, pid) in [
        (0x16c0u16, 0x0483u16),
        (0x1234, 0x0006),
        (0x2341, 0x003d),
        (0x0403, 0xcb48),
    ] {
        assert_ne!(recognise_usb(vid, pid, None), Recognised::Unknown);
        let needle_vid = format!("{{idVendor}}==\"{vid:04x}\"");
        let needle_pid = format!("{{idProduct}}==\"{pid:04x}\"");
        assert!(
            rules
                .lines()
                .filter(|l| !l.starts_with('#'))
                .any(|l| l.contains(&needle_vid)
                    && l.contains(&needle_pid)
                    && l.contains("MODE=\"0660\"")),
            "no access rule for {vid:04x}:{pid:04x}"
        );
    }
    assert!(rules.contains("ATTRS{product}==\"*[Vv]oxhap*\""));
}
