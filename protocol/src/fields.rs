//! Small field types that messages carry: the protocol version, bit sets (force flags, status, faults, supported
//! rates), fault and rejection codes, and fixed-size ASCII labels. Each is a thin newtype over the wire integer so
//! that unknown bits and codes from a newer minor version pass through unchanged (see SPEC.md, "Versioning").

/// A protocol version. Peers must agree on `major`; `minor` only adds message types, flag bits and codes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Version {
    /// Incompatible layout changes bump this.
    pub major: u8,
    /// Backwards-compatible additions bump this.
    pub minor: u8,
}

impl Version {
    /// True if a peer speaking `other` can talk to one speaking `self` (same major version).
    pub const fn is_compatible_with(self, other: Version) -> bool {
        self.major == other.major
    }

    /// True if `self` is `other` or a later minor version of the same major (it has everything `other` added).
    pub const fn includes(self, other: Version) -> bool {
        self.major == other.major && self.minor >= other.minor
    }
}

/// The version this crate implements: 1.1 (1.0 plus the optional local-model capability, SPEC section 10).
pub const PROTOCOL_VERSION: Version = Version { major: 1, minor: 1 };

/// The first version with the local-model capability (SPEC section 10.1). A device of an earlier minor version
/// never gets a LocalModel, whatever its status bits say (bit 6 is reserved there).
pub const LOCAL_MODEL_VERSION: Version = Version { major: 1, minor: 1 };

/// SPEC section 10.1: the host may send LocalModel to a device that announced `device_version` in DeviceInfo and
/// `status` in the HeartbeatReply confirming that DeviceInfo only when the version is 1.1 or later (of the same
/// major) and `LOCAL_MODEL` is set. Any other device (1.0, or 1.1 without the bit) keeps the SetForce path.
pub const fn local_model_negotiated(device_version: Version, status: StatusFlags) -> bool {
    device_version.includes(LOCAL_MODEL_VERSION) && status.contains(StatusFlags::LOCAL_MODEL)
}

macro_rules! bit_set {
    ($(#[$meta:meta])* $name:ident($int:ty) { $($(#[$bit_meta:meta])* $bit:ident = $value:expr;)* }) => {
        $(#[$meta])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
        pub struct $name(pub $int);

        impl $name {
            $($(#[$bit_meta])* pub const $bit: $name = $name($value);)*
            /// No bit set.
            pub const EMPTY: $name = $name(0);

            /// True if every bit of `other` is set in `self`.
            pub const fn contains(self, other: $name) -> bool {
                self.0 & other.0 == other.0
            }

            /// True if no bit is set.
            pub const fn is_empty(self) -> bool {
                self.0 == 0
            }

            /// `self` with the bits of `other` set or cleared.
            #[must_use]
            pub const fn with(self, other: $name, on: bool) -> $name {
                if on { $name(self.0 | other.0) } else { $name(self.0 & !other.0) }
            }
        }

        impl core::ops::BitOr for $name {
            type Output = $name;
            fn bitor(self, rhs: $name) -> $name {
                $name(self.0 | rhs.0)
            }
        }
    };
}
pub(crate) use bit_set;

bit_set! {
    /// Flags of a set-force message. Senders write unknown bits as zero; receivers ignore them.
    ForceFlags(u16) {
        /// Ask the device for one state frame in reply, even when it streams at a fixed rate.
        REQUEST_STATE = 1 << 0;
    }
}

bit_set! {
    /// Device status bits, in state and heartbeat messages. Receivers ignore unknown bits.
    StatusFlags(u16) {
        /// A hello with a compatible major version opened the session.
        SESSION_OPEN = 1 << 0;
        /// Forces from set-force messages are applied.
        ENABLED = 1 << 1;
        /// A latched fault holds the device at zero force until clear-fault.
        FAULTED = 1 << 2;
        /// The watchdog dropped the device to zero force since the last enable.
        WATCHDOG_TRIPPED = 1 << 3;
        /// The force being applied (only while enabled) was scaled down to the device's maximum force.
        FORCE_CLAMPED = 1 << 4;
        /// State frames answer set-force messages (state rate 0) instead of streaming at a fixed rate.
        LOCKSTEP = 1 << 5;
        /// The device implements the local-model capability (SPEC section 10): it accepts LocalModel messages and
        /// reports its local loop in LocalState. Set in every State and HeartbeatReply of a capable device.
        LOCAL_MODEL = 1 << 6;
    }
}

bit_set! {
    /// Latched faults: bit `n` is set while fault code `n` is active. Bit 0 (the watchdog) never latches.
    FaultFlags(u16) {
    }
}

impl FaultFlags {
    /// The bit of one fault code.
    pub const fn of(code: FaultCode) -> FaultFlags {
        FaultFlags(1 << (code.0 & 15))
    }
}

/// Why the device dropped to zero force. Codes 0..=15; each latching code has a bit in [`FaultFlags`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct FaultCode(pub u8);

impl FaultCode {
    /// No set-force arrived within the watchdog timeout while enabled. Does not latch: the device goes to idle.
    pub const WATCHDOG_EXPIRED: FaultCode = FaultCode(0);
    /// The emergency stop input is active.
    pub const EMERGENCY_STOP: FaultCode = FaultCode(1);
    /// A motor or driver is too hot.
    pub const OVER_TEMPERATURE: FaultCode = FaultCode(2);
    /// A motor current exceeded its limit.
    pub const OVER_CURRENT: FaultCode = FaultCode(3);
    /// Position sensing failed (encoder error, or a non-finite position or velocity).
    pub const ENCODER: FaultCode = FaultCode(4);
    /// A motor amplifier reported a fault.
    pub const AMPLIFIER: FaultCode = FaultCode(5);
    /// The supply voltage is outside its range.
    pub const SUPPLY_VOLTAGE: FaultCode = FaultCode(6);
    /// Any other firmware fault.
    pub const INTERNAL: FaultCode = FaultCode(7);
    /// Largest valid code.
    pub const MAX: u8 = 15;

    /// True for every code but the watchdog: the device stays faulted until clear-fault.
    pub const fn is_latching(self) -> bool {
        self.0 != Self::WATCHDOG_EXPIRED.0
    }
}

/// Why the device refused a host message (in a rejected message).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct RejectReason(pub u8);

impl RejectReason {
    /// The message needs an open session: send hello first.
    pub const NO_SESSION: RejectReason = RejectReason(1);
    /// The hello's major version differs from the device's.
    pub const VERSION_MISMATCH: RejectReason = RejectReason(2);
    /// The device is faulted: send clear-fault first.
    pub const FAULTED: RejectReason = RejectReason(3);
    /// A field is outside the range the device accepts (watchdog timeout, unsupported state rate).
    pub const INVALID_ARGUMENT: RejectReason = RejectReason(4);
}

/// The state rates a device can sustain, as a bit set over [`RateSet::RATES_HZ`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct RateSet(pub u8);

impl RateSet {
    /// Bit `n` of a rate set stands for `RATES_HZ[n]` hertz.
    pub const RATES_HZ: [u16; 8] = [100, 200, 250, 500, 1000, 2000, 4000, 8000];

    /// The set holding exactly the given rates, or `None` if one of them is not in [`Self::RATES_HZ`].
    pub fn from_rates_hz(rates_hz: &[u16]) -> Option<RateSet> {
        let mut bits = 0u8;
        for &rate in rates_hz {
            let index = Self::RATES_HZ.iter().position(|&r| r == rate)?;
            bits |= 1 << index;
        }
        Some(RateSet(bits))
    }

    /// True if `rate_hz` is in the set.
    pub fn contains_hz(self, rate_hz: u16) -> bool {
        Self::RATES_HZ
            .iter()
            .enumerate()
            .any(|(bit, &rate)| rate == rate_hz && self.0 & (1 << bit) != 0)
    }

    /// The rates in the set, slowest first.
    pub fn iter_hz(self) -> impl Iterator<Item = u16> {
        Self::RATES_HZ
            .into_iter()
            .enumerate()
            .filter(move |(bit, _)| self.0 & (1 << bit) != 0)
            .map(|(_, r)| r)
    }
}

/// Length of the model and serial-number labels in device info.
pub const LABEL_LEN: usize = 12;

/// A fixed 12-byte text field: printable ASCII (0x20..=0x7E), then zero padding.
#[derive(Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Label([u8; LABEL_LEN]);

/// A string that cannot be a [`Label`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum LabelError {
    /// More than 12 bytes.
    #[error("label of {len} bytes is longer than 12")]
    TooLong {
        /// Length of the string in bytes.
        len: usize,
    },
    /// A byte outside printable ASCII.
    #[error("label byte 0x{byte:02x} is not printable ASCII")]
    NotPrintable {
        /// The offending byte.
        byte: u8,
    },
}

impl Label {
    /// The label holding `text`, which must be at most 12 bytes of printable ASCII.
    pub fn new(text: &str) -> Result<Label, LabelError> {
        let bytes = text.as_bytes();
        if bytes.len() > LABEL_LEN {
            return Err(LabelError::TooLong { len: bytes.len() });
        }
        let mut out = [0u8; LABEL_LEN];
        for (slot, &byte) in out.iter_mut().zip(bytes) {
            if !(0x20..=0x7E).contains(&byte) {
                return Err(LabelError::NotPrintable { byte });
            }
            *slot = byte;
        }
        Ok(Label(out))
    }

    /// Checks the wire bytes: printable ASCII, then only zeros.
    pub fn from_bytes(bytes: [u8; LABEL_LEN]) -> Option<Label> {
        let text_len = bytes.iter().position(|&b| b == 0).unwrap_or(LABEL_LEN);
        let text_ok = bytes[..text_len].iter().all(|b| (0x20..=0x7E).contains(b));
        let padding_ok = bytes[text_len..].iter().all(|&b| b == 0);
        (text_ok && padding_ok).then_some(Label(bytes))
    }

    /// The wire bytes.
    pub const fn to_bytes(self) -> [u8; LABEL_LEN] {
        self.0
    }

    /// The text, without padding.
    pub fn as_str(&self) -> &str {
        let len = self.0.iter().position(|&b| b == 0).unwrap_or(LABEL_LEN);
        // Printable ASCII is valid UTF-8; both constructors guarantee it.
        core::str::from_utf8(&self.0[..len]).unwrap_or("")
    }
}

impl core::fmt::Debug for Label {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        core::fmt::Debug::fmt(self.as_str(), f)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn label_accepts_printable_ascii_and_refuses_the_rest() {
        assert_eq!(
            Label::new("Falcon 3").map(|l| l.as_str() == "Falcon 3"),
            Ok(true)
        );
        assert_eq!(
            Label::new("thirteen byte"),
            Err(LabelError::TooLong { len: 13 })
        );
        assert_eq!(
            Label::new("tab\t"),
            Err(LabelError::NotPrintable { byte: b'\t' })
        );
        assert!(Label::from_bytes(*b"abc\0\0\0\0\0\0\0\0\0").is_some());
        assert!(
            Label::from_bytes(*b"abc\0x\0\0\0\0\0\0\0").is_none(),
            "text after padding"
        );
        assert!(
            Label::from_bytes(*b"ab\xffc\0\0\0\0\0\0\0\0").is_none(),
            "non-ASCII byte"
        );
    }

    #[test]
    fn rate_set_maps_bits_to_rates() {
        let set = RateSet::from_rates_hz(&[1000, 250]);
        assert_eq!(set, Some(RateSet(0b0001_0100)));
        let set = set.unwrap_or_default();
        assert!(set.contains_hz(1000) && set.contains_hz(250) && !set.contains_hz(500));
        assert!(set.iter_hz().eq([250, 1000]));
        assert_eq!(RateSet::from_rates_hz(&[300]), None);
    }

    #[test]
    fn fault_bits_follow_codes() {
        assert_eq!(FaultFlags::of(FaultCode::OVER_CURRENT), FaultFlags(0b1000));
        assert!(!FaultCode::WATCHDOG_EXPIRED.is_latching());
        assert!(FaultCode::EMERGENCY_STOP.is_latching());
    }

    #[test]
    fn versions_agree_on_major_only() {
        assert!(PROTOCOL_VERSION.is_compatible_with(Version { major: 1, minor: 7 }));
        assert!(PROTOCOL_VERSION.is_compatible_with(Version { major: 1, minor: 0 }));
        assert!(!PROTOCOL_VERSION.is_compatible_with(Version { major: 2, minor: 0 }));
    }

    #[test]
    fn local_models_need_version_1_1_and_the_status_bit() {
        // SPEC section 10.1, each case of the rule.
        let v = |major, minor| Version { major, minor };
        let capable = StatusFlags::SESSION_OPEN | StatusFlags::LOCAL_MODEL;
        assert_eq!(PROTOCOL_VERSION, v(1, 1));
        assert!(local_model_negotiated(v(1, 1), capable));
        assert!(local_model_negotiated(v(1, 9), capable));
        assert!(
            !local_model_negotiated(v(1, 0), capable),
            "bit 6 is reserved in 1.0"
        );
        assert!(!local_model_negotiated(v(1, 1), StatusFlags::SESSION_OPEN));
        assert!(!local_model_negotiated(v(2, 1), capable));
        assert!(!local_model_negotiated(v(0, 5), capable));
    }
}
