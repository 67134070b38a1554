//! Every message of both directions survives serial and HID encoding unchanged, frames have the promised shape,
//! and encoders refuse what decoders would reject.

use proptest::prelude::*;
use voxhap_protocol::{
    decode_frame, decode_report, encode_frame, encode_report, hid, DeviceToHost, EncodeError,
    ForceFlags, HostToDevice, Message, PayloadError, SetForce, MAX_PAYLOAD_LEN, MAX_WIRE_FRAME_LEN,
};

use crate::strategies::{device_to_host, host_to_device};

fn serial_round_trip<M: Message>(message: &M) -> Result<(), TestCaseError> {
    let mut buf = [0xAAu8; MAX_WIRE_FRAME_LEN];
    let len = encode_frame(message, &mut buf).expect("valid messages encode");
    let payload_len = M::payload_len(message.message_type()).expect("known type");
    prop_assert!(payload_len <= MAX_PAYLOAD_LEN);
    // type + payload + CRC, one COBS overhead byte, one delimiter.
    prop_assert_eq!(len, 1 + payload_len + 2 + 1 + 1);
    prop_assert!(!buf[..len - 1].contains(&0), "stuffed frame holds a zero");
    prop_assert_eq!(buf[len - 1], 0);
    prop_assert_eq!(decode_frame::<M>(&buf[..len]), Ok((*message, len)));
    // One byte short of the delimiter is incomplete, never an error.
    prop_assert_eq!(
        decode_frame::<M>(&buf[..len - 1]).err(),
        Some(voxhap_protocol::SliceError::Incomplete)
    );
    Ok(())
}

fn hid_round_trip<M: Message>(message: &M) -> Result<(), TestCaseError> {
    let mut report = [0xAAu8; hid::REPORT_LEN];
    prop_assert_eq!(encode_report(message, &mut report), Ok(hid::REPORT_LEN));
    prop_assert_eq!(report[0], M::HID_REPORT_ID);
    prop_assert_eq!(report[1], message.message_type());
    let used = 2 + M::payload_len(message.message_type()).expect("known type");
    prop_assert!(report[used..].iter().all(|&b| b == 0), "padding not zero");
    prop_assert_eq!(decode_report::<M>(&report), Ok(*message));
    // Stacks that strip the padding still decode.
    prop_assert_eq!(decode_report::<M>(&report[..used]), Ok(*message));
    Ok(())
}

proptest! {
    #[test]
    fn host_to_device_round_trips(message in host_to_device()) {
        serial_round_trip(&message)?;
        hid_round_trip(&message)?;
    }

    #[test]
    fn device_to_host_round_trips(message in device_to_host()) {
        serial_round_trip(&message)?;
        hid_round_trip(&message)?;
    }

    #[test]
    fn bits_of_floats_survive(bits in any::<[u32; 3]>()) {
        let force_n = bits.map(f32::from_bits);
        prop_assume!(force_n.iter().all(|f| f.is_finite()));
        let message = HostToDevice::SetForce(SetForce { sequence: 1, force_n, flags: ForceFlags::EMPTY });
        let mut buf = [0u8; MAX_WIRE_FRAME_LEN];
        let len = encode_frame(&message, &mut buf).expect("finite force encodes");
        let Ok((HostToDevice::SetForce(back), _)) = decode_frame::<HostToDevice>(&buf[..len]) else {
            return Err(TestCaseError::fail("set-force did not decode"));
        };
        prop_assert_eq!(back.force_n.map(f32::to_bits), bits);
    }

    #[test]
    fn encoders_refuse_non_finite_forces(axis in 0usize..3, bad in prop_oneof![Just(f32::NAN), Just(f32::INFINITY), Just(f32::NEG_INFINITY)]) {
        let mut force_n = [0.0f32; 3];
        force_n[axis] = bad;
        let message = HostToDevice::SetForce(SetForce { sequence: 9, force_n, flags: ForceFlags::EMPTY });
        let refused = EncodeError::Invalid(PayloadError::NonFinite { message_type: 0x04, field: "force_n" });
        prop_assert_eq!(encode_frame(&message, &mut [0u8; MAX_WIRE_FRAME_LEN]), Err(refused));
        prop_assert_eq!(encode_report(&message, &mut [0u8; hid::REPORT_LEN]), Err(refused));
    }
}

#[test]
fn small_output_buffer_is_an_error_not_a_truncation() {
    let message = DeviceToHost::Rejected(voxhap_protocol::Rejected {
        message_type: 2,
        reason: voxhap_protocol::RejectReason::FAULTED,
    });
    let mut buf = [0u8; 6];
    assert_eq!(
        encode_frame(&message, &mut buf),
        Err(EncodeError::BufferTooSmall {
            needed: 7,
            available: 6
        })
    );
    let mut buf = [0u8; 7];
    assert_eq!(encode_frame(&message, &mut buf), Ok(7));
}
