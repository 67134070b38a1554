//! Tests of `codec`.

use super::*;

#[test]
fn crc64_matches_the_ecma_182_check_value_and_the_reference_table() {
    // CRC-64/ECMA-182 of "123456789" (init 0, no reflection, no final xor).
    assert_eq!(crc64(b"123456789"), 0x6C40_DF5F_0B49_7347);
    // The first entries of igtl_util.c's table.
    assert_eq!(CRC_TABLE[1], 0x42F0_E1EB_A9EA_3693);
    assert_eq!(CRC_TABLE[2], 0x85E1_C3D7_53D4_6D26);
    assert_eq!(CRC_TABLE[255], 0x9AFC_E626_CE85_B507);
    assert_eq!(crc64(b""), 0);
}

fn header_of(bytes: &[u8]) -> Header {
    let fixed: &[u8; HEADER_BYTES] = bytes[..HEADER_BYTES].try_into().unwrap();
    Header::decode(fixed, 1 << 20).unwrap()
}

#[test]
fn a_transform_round_trips_in_both_header_versions() {
    let transform = Transform {
        rotation: DMat3::from_cols(DVec3::Y, -DVec3::X, DVec3::Z),
        translation: DVec3::new(12.5, -3.0, 40.0),
    };
    for version in [1u16, 2] {
        let mut out = Vec::new();
        encode_message(
            &mut out,
            version,
            "TRANSFORM",
            "Probe",
            7 << 32,
            &[("a", "b")],
            |o| transform.encode(o),
        );
        let header = header_of(&out);
        assert_eq!(header.version, version);
        assert_eq!(header.type_name, "TRANSFORM");
        assert_eq!(header.device_name, "Probe");
        assert_eq!(header.timestamp, 7 << 32);
        let body = &out[HEADER_BYTES..];
        assert_eq!(header.body_size as usize, body.len());
        header.check_crc(body).unwrap();
        let split = Body::split(version, body).unwrap();
        assert_eq!(split.content.len(), TRANSFORM_BYTES);
        assert_eq!(Transform::decode(split.content).unwrap(), transform);
        if version == 2 {
            assert_eq!(split.metadata_value("a"), Some("b"));
        } else {
            assert!(split.metadata.is_empty());
        }
    }
}

#[test]
fn a_flipped_bit_fails_the_crc_and_bad_headers_say_why() {
    let mut out = Vec::new();
    encode_message(&mut out, 1, "STATUS", "voxhap", 0, &[], |o| {
        encode_status(o, status_code::OK, 0, "OK", "fine")
    });
    let header = header_of(&out);
    let mut body = out[HEADER_BYTES..].to_vec();
    assert_eq!(decode_status(&body).unwrap().message, "fine");
    body[3] ^= 1;
    assert!(matches!(
        header.check_crc(&body),
        Err(CodecError::Crc { .. })
    ));
    let mut bad = out.clone();
    bad[1] = 9;
    let fixed: &[u8; HEADER_BYTES] = bad[..HEADER_BYTES].try_into().unwrap();
    assert_eq!(
        Header::decode(fixed, 100),
        Err(CodecError::HeaderVersion(9))
    );
    let fixed: &[u8; HEADER_BYTES] = out[..HEADER_BYTES].try_into().unwrap();
    assert!(matches!(
        Header::decode(fixed, 4),
        Err(CodecError::BodyTooLarge { .. })
    ));
}

#[test]
fn strings_and_metadata_decode_or_say_why() {
    let mut content = Vec::new();
    encode_string(&mut content, "token abc");
    assert_eq!(decode_string(&content).unwrap(), "token abc");
    content.push(b'x');
    assert!(decode_string(&content).is_err());
    // A metadata entry that claims more bytes than there are.
    let mut body = vec![0, 12, 0, 10, 0, 0, 0, 1, 0, 0, 0, 0];
    body.extend_from_slice(&[0, 1, 0, 5, 0, 3, 0, 0, 0, 9]);
    body.push(b'k');
    assert!(matches!(
        Body::split(2, &body),
        Err(CodecError::Metadata(_))
    ));
    // Sizes that add up to more than the body.
    body[7] = 200;
    assert!(matches!(
        Body::split(2, &body),
        Err(CodecError::ExtendedHeader(_))
    ));
    assert!(Body::split(2, &[0, 12]).is_err());
}

#[test]
fn an_image_round_trips_with_its_centre_and_lps_is_flipped() {
    let image = Image::ramp([3, 2, 2], [0.5, 1.0, 2.0], [-10.0, 5.0, 1.0]);
    let mut content = Vec::new();
    encode_image(&mut content, &image);
    let back = decode_image(&content, 1000).unwrap();
    assert_eq!(back, image);
    // Centre of a 3 x 2 x 2 image: origin + (1, 0.5, 0.5) voxels.
    assert_eq!(f32_at(&content, 12 + 36), -9.5);
    content[5] = 2; // LPS
    let lps = decode_image(&content, 1000).unwrap();
    assert_eq!(lps.origin_mm.z, 1.0);
    assert_eq!(lps.axes_mm.x_axis, DVec3::new(-0.5, 0.0, 0.0));
    assert!(decode_image(&content, 11).is_err());
    let mut partial = content.clone();
    partial[66..68].copy_from_slice(&1u16.to_be_bytes());
    assert!(decode_image(&partial, 1000)
        .unwrap_err()
        .to_string()
        .contains("partial"));
    assert!(decode_image(&content[..content.len() - 1], 1000).is_err());
}

#[test]
fn timestamps_carry_seconds_and_a_binary_fraction() {
    let ts = timestamp_from_unix_ns(1_500_000_000);
    assert_eq!(ts >> 32, 1);
    assert_eq!(ts & 0xFFFF_FFFF, 1 << 31);
}

proptest::proptest! {
    /// Arbitrary bytes never panic the decoders.
    #[test]
    fn decoders_never_panic(bytes in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..200)) {
        let _ = Body::split(2, &bytes);
        let _ = Transform::decode(&bytes);
        let _ = decode_status(&bytes);
        let _ = decode_string(&bytes);
        let _ = decode_image(&bytes, 1000);
        if bytes.len() >= HEADER_BYTES {
            let fixed: &[u8; HEADER_BYTES] = bytes[..HEADER_BYTES].try_into().unwrap();
            let _ = Header::decode(fixed, 1 << 20);
        }
    }
}
