//! A C interface to `voxhap-local`: the device side of the local-model capability (protocol/SPEC.md
//! section 10) behind `#[no_mangle] extern "C"` functions, for a firmware written in C. `include/voxhap_local.h`
//! declares them; docs/local-model.md ("Linking from C") shows their use.
//!
//! One device is a [`Device`]: the frame decoder, the protocol's device session (with the capability) and the
//! local loop. It lives in storage the caller provides (a static array, say), at least
//! [`voxhap_local_storage_size`] bytes aligned to [`voxhap_local_storage_align`]; nothing is allocated and nothing
//! here needs the standard library. Every function checks its pointers and returns a negative
//! `VOXHAP_LOCAL_E*` code instead of touching memory it was not given.
#![no_std]
#![deny(missing_docs)]

use core::mem::{align_of, size_of};
use voxhap_local::{LocalLoop, LoopConfig};
use voxhap_protocol::{
    encode_frame, DeviceInfo, DeviceSample, DeviceSession, FrameDecoder, HostToDevice, Label,
    RateSet, MAX_WIRE_FRAME_LEN, PROTOCOL_VERSION,
};

#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    // Nothing here panics on any input (the functions check their arguments); if it ever did, stop.
    loop {}
}

/// The precompiled `core` of hosted targets carries unwind tables that name this symbol; with
/// `panic = "abort"` nothing unwinds, so it is never called. Without it a C link on such a target fails.
#[no_mangle]
pub extern "C" fn rust_eh_personality() {}

/// Success.
pub const VOXHAP_LOCAL_OK: i32 = 0;
/// A pointer argument was null.
pub const VOXHAP_LOCAL_ENULL: i32 = -1;
/// The storage is smaller than [`voxhap_local_storage_size`] or not aligned to [`voxhap_local_storage_align`].
pub const VOXHAP_LOCAL_ESTORAGE: i32 = -2;
/// The device description is invalid (a non-finite or negative value, a label that is not printable ASCII).
pub const VOXHAP_LOCAL_EINFO: i32 = -3;
/// The storage does not hold an initialised device (no `voxhap_local_init` on it).
pub const VOXHAP_LOCAL_EINIT: i32 = -4;
/// The output buffer is smaller than `VOXHAP_LOCAL_MAX_FRAME` bytes.
pub const VOXHAP_LOCAL_EBUFFER: i32 = -5;

/// Marks initialised storage ("VXLOCAL1").
const MAGIC: u64 = 0x5658_4C4F_4341_4C31;

/// What a firmware says about its device (SPEC section 3.2, DeviceInfo), as C sees it.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct VoxhapLocalInfo {
    /// Model name: printable ASCII, at most 12 bytes, zero-terminated if shorter.
    pub model: [u8; 12],
    /// Serial number, as `model`.
    pub serial_number: [u8; 12],
    /// Sensed and actuated degrees of freedom (3 for a local-model device), buttons.
    pub position_dof: u8,
    /// Actuated degrees of freedom.
    pub force_dof: u8,
    /// Buttons reported in State.
    pub button_count: u8,
    /// Bit set over SPEC's rate table (bit 3: 500 Hz, bit 4: 1000 Hz, ...).
    pub supported_rates: u8,
    /// Lower corner of the reachable box, m.
    pub workspace_min_m: [f32; 3],
    /// Upper corner, m.
    pub workspace_max_m: [f32; 3],
    /// The device's force clamp, N.
    pub max_force_n: f32,
    /// Largest stiffness rendered stably at 1 kHz, N/m.
    pub max_stiffness_n_per_m: f32,
}

/// One device: decoder, session, local loop. `repr(C)` keeps the marker first, where an initialised storage
/// has it.
#[repr(C)]
pub struct Device {
    magic: u64,
    decoder: FrameDecoder<HostToDevice>,
    session: DeviceSession,
    local: LocalLoop,
}

/// Bytes of storage one device needs.
#[no_mangle]
pub extern "C" fn voxhap_local_storage_size() -> usize {
    size_of::<Device>()
}

/// Alignment the storage needs, bytes.
#[no_mangle]
pub extern "C" fn voxhap_local_storage_align() -> usize {
    align_of::<Device>()
}

fn label(bytes: &[u8; 12]) -> Option<Label> {
    let len = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    let text = core::str::from_utf8(&bytes[..len]).ok()?;
    Label::new(text).ok()
}

fn device_info(info: &VoxhapLocalInfo) -> Option<DeviceInfo> {
    let finite = info
        .workspace_min_m
        .iter()
        .chain(&info.workspace_max_m)
        .chain([&info.max_force_n, &info.max_stiffness_n_per_m])
        .all(|v| v.is_finite());
    let ordered = (0..3).all(|i| info.workspace_min_m[i] <= info.workspace_max_m[i]);
    let dof_ok = info.position_dof <= 6 && info.force_dof <= 6 && info.button_count <= 16;
    if !finite || !ordered || !dof_ok || info.max_force_n < 0.0 || info.max_stiffness_n_per_m < 0.0
    {
        return None;
    }
    Some(DeviceInfo {
        version: PROTOCOL_VERSION,
        model: label(&info.model)?,
        serial_number: label(&info.serial_number)?,
        position_dof: info.position_dof,
        force_dof: info.force_dof,
        button_count: info.button_count,
        supported_rates: RateSet(info.supported_rates),
        workspace_min_m: info.workspace_min_m,
        workspace_max_m: info.workspace_max_m,
        max_force_n: info.max_force_n,
        max_stiffness_n_per_m: info.max_stiffness_n_per_m,
    })
}

fn storage_ok(storage: *mut u8, len: usize) -> i32 {
    if storage.is_null() {
        VOXHAP_LOCAL_ENULL
    } else if len < size_of::<Device>() || !storage.cast::<Device>().is_aligned() {
        VOXHAP_LOCAL_ESTORAGE
    } else {
        VOXHAP_LOCAL_OK
    }
}

/// The device in `storage`, if it is one `voxhap_local_init` made.
///
/// # Safety
/// `storage` must be null or point to `len` bytes the caller owns and does not touch meanwhile.
unsafe fn device<'a>(storage: *mut u8, len: usize) -> Result<&'a mut Device, i32> {
    match storage_ok(storage, len) {
        VOXHAP_LOCAL_OK => {}
        error => return Err(error),
    }
    // The magic is the first field; read it before taking a reference to the whole device.
    let magic = unsafe { core::ptr::addr_of!((*storage.cast::<Device>()).magic).read() };
    if magic != MAGIC {
        return Err(VOXHAP_LOCAL_EINIT);
    }
    Ok(unsafe { &mut *storage.cast::<Device>() })
}

/// Builds a powered-up device with the local-model capability in `storage` (`len` bytes): session closed,
/// drive idle, zero force; its local loop assumes `period_us` for the first cycle (0: 100 µs). Announces
/// protocol 1.1 and sets `LOCAL_MODEL` in every status word.
///
/// # Safety
/// `storage` must be null or point to `len` writable bytes owned by the caller for as long as the device is
/// used; `info` must be null or point to a valid `VoxhapLocalInfo`.
#[no_mangle]
pub unsafe extern "C" fn voxhap_local_init(
    storage: *mut u8,
    len: usize,
    info: *const VoxhapLocalInfo,
    period_us: u32,
) -> i32 {
    match storage_ok(storage, len) {
        VOXHAP_LOCAL_OK => {}
        error => return error,
    }
    if info.is_null() {
        return VOXHAP_LOCAL_ENULL;
    }
    let Some(info) = device_info(unsafe { &*info }) else {
        return VOXHAP_LOCAL_EINFO;
    };
    let config = LoopConfig {
        period_us: if period_us == 0 { 100 } else { period_us },
        ..LoopConfig::default()
    };
    let device = Device {
        magic: MAGIC,
        decoder: FrameDecoder::new(),
        session: DeviceSession::with_local_model(info),
        local: LocalLoop::new(config),
    };
    unsafe { core::ptr::write(storage.cast::<Device>(), device) };
    VOXHAP_LOCAL_OK
}

/// Hands `n` bytes received from the host (serial framing, SPEC section 4) to the device at device time
/// `now_us`; whole messages go to the session. Returns the number of messages taken, or a negative code.
///
/// # Safety
/// `storage` as for `voxhap_local_init`; `bytes` must be null or point to `n` readable bytes.
#[no_mangle]
pub unsafe extern "C" fn voxhap_local_receive(
    storage: *mut u8,
    len: usize,
    bytes: *const u8,
    n: usize,
    now_us: u64,
) -> i32 {
    let device = match unsafe { device(storage, len) } {
        Ok(device) => device,
        Err(error) => return error,
    };
    if bytes.is_null() && n > 0 {
        return VOXHAP_LOCAL_ENULL;
    }
    let received = if n == 0 {
        &[][..]
    } else {
        unsafe { core::slice::from_raw_parts(bytes, n) }
    };
    let mut taken: i32 = 0;
    for &byte in received {
        if let Some(Ok(message)) = device.decoder.push(byte) {
            device.session.on_message(&message, now_us);
            taken = taken.saturating_add(1);
        }
    }
    taken
}

/// One control cycle at device time `now_us` with the sensed handle (position, m; velocity, m/s; buttons):
/// the session's watchdog and State frames, then the local model if one is in use (SPEC section 10.5), else
/// the SetForce path. Writes the force to apply (N, device frame) to `force_n`; zero on any error.
///
/// # Safety
/// `storage` as for `voxhap_local_init`; `position_m`, `velocity_m_per_s` and `force_n` must be null or point
/// to three floats each.
#[no_mangle]
pub unsafe extern "C" fn voxhap_local_step(
    storage: *mut u8,
    len: usize,
    now_us: u64,
    position_m: *const f32,
    velocity_m_per_s: *const f32,
    buttons: u16,
    force_n: *mut f32,
) -> i32 {
    if force_n.is_null() {
        return VOXHAP_LOCAL_ENULL;
    }
    let out = unsafe { core::slice::from_raw_parts_mut(force_n, 3) };
    out.fill(0.0);
    let device = match unsafe { device(storage, len) } {
        Ok(device) => device,
        Err(error) => return error,
    };
    if position_m.is_null() || velocity_m_per_s.is_null() {
        return VOXHAP_LOCAL_ENULL;
    }
    let three = |p: *const f32| {
        let s = unsafe { core::slice::from_raw_parts(p, 3) };
        [s[0], s[1], s[2]]
    };
    let sample = DeviceSample {
        position_m: three(position_m),
        velocity_m_per_s: three(velocity_m_per_s),
        buttons,
    };
    let force = device.local.step(&mut device.session, now_us, &sample);
    // The loop never returns a non-finite force; a firmware must never apply one, so check anyway.
    if force.iter().all(|f| f.is_finite()) {
        out.copy_from_slice(&force);
    }
    VOXHAP_LOCAL_OK
}

/// The next frame to send to the host, serial framing with its delimiter, written to `out` (at least
/// `VOXHAP_LOCAL_MAX_FRAME` bytes). Returns its length, 0 when nothing is queued, or a negative code. Call it
/// until it returns 0 after every cycle (SPEC section 6.7).
///
/// # Safety
/// `storage` as for `voxhap_local_init`; `out` must be null or point to `out_len` writable bytes.
#[no_mangle]
pub unsafe extern "C" fn voxhap_local_transmit(
    storage: *mut u8,
    len: usize,
    out: *mut u8,
    out_len: usize,
) -> i32 {
    let device = match unsafe { device(storage, len) } {
        Ok(device) => device,
        Err(error) => return error,
    };
    if out.is_null() {
        return VOXHAP_LOCAL_ENULL;
    }
    if out_len < MAX_WIRE_FRAME_LEN {
        return VOXHAP_LOCAL_EBUFFER;
    }
    let buffer = unsafe { core::slice::from_raw_parts_mut(out, out_len) };
    while let Some(message) = device.session.poll_transmit() {
        // Every message the session queues encodes (finite by construction); skip one that would not.
        if let Ok(written) = encode_frame(&message, buffer) {
            return i32::try_from(written).unwrap_or(0);
        }
    }
    0
}

/// Status bits the device reports (SPEC section 6.1), for a firmware's own display; `LOCAL_MODEL` always set.
///
/// # Safety
/// `storage` as for `voxhap_local_init`.
#[no_mangle]
pub unsafe extern "C" fn voxhap_local_status(storage: *mut u8, len: usize) -> i32 {
    match unsafe { device(storage, len) } {
        Ok(device) => i32::from(device.session.status().0),
        Err(error) => error,
    }
}

/// Largest frame `voxhap_local_transmit` writes, bytes (checked against the header's constant by the C test).
#[no_mangle]
pub extern "C" fn voxhap_local_max_frame() -> usize {
    MAX_WIRE_FRAME_LEN
}
