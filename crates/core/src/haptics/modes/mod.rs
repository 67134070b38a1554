//! Haptic modes (docs/modes.md): from volume data at the proxy to haptic primitives.
//!
//! Place in the data flow: each servo tick, [`crate::haptics::tick`] asks every mode of the
//! [`RenderScene`] to sample its volume at the current proxy position (the proxy at the start of the
//! tick) and to push at most one [`Primitive`] into the tick's preallocated buffer; the solver then
//! balances all of them against the coupling. Modes combine freely, over any of the scene's volumes: a
//! surface from one volume and a flow constraint from another give the non-orthogonal constraints the
//! primitives method exists for.
//!
//! What each mode emits (`x` the proxy at the start of the tick, `TF` the mode's [`TransferFunction`]).
//! The start-of-tick proxy is where the previous tick left it, so "a point at the previous proxy
//! position" (docs/modes.md) is a point at `x`, and it resists the proxy's motion during this tick:
//!
//! | mode | reads | emits |
//! |---|---|---|
//! | surface | scalar `V` | plane through `x`, normal `-grad V/abs(grad V)` (side `outward`, default) or `+grad V/abs(grad V)` (`inward`), strength `TF(V)` |
//! | friction | a surface mode | point at `x`, strength `mu N` (N below) |
//! | viscosity | scalar `V` | point at `x`, strength `TF(V)` |
//! | vector follow | vector `v` | line through `x` along `v/abs(v)`, strength `TF(abs(v))` |
//! | vortex | vector `v` | line along `w/abs(w)`, `w = curl v`, through the linearised core (below), strength `TF(abs(w))` |
//! | vector force | vector `v` | directed force along `v/abs(v)`, strength `TF(abs(v))` |
//! | gradient force | scalar `V` | directed force along `grad V/abs(grad V)`, strength `TF(abs(grad V))` |
//! | support plane | nothing | the fixed plane the user placed |
//!
//! Where the direction is undefined (zero gradient, zero vector, zero curl) or the strength is zero, the
//! mode emits nothing that tick.
//!
//! **Friction's normal force.** The solver does not expose its dual variables per primitive, so `N` is
//! the simplest honest estimate available without them: the previous tick's device force
//! `F = k (proxy - probe)` resolved along the normal of the plane the surface mode emitted in that tick,
//! `N = max(0, n . F)`. At equilibrium `F` balances the sum of primitive forces, so when the surface plane
//! is the only primitive pushing along `n` this is exactly the plane's force. When the surface emitted no
//! plane last tick, `N = 0` and friction emits nothing. Friction uses a point (as the paper does), so it
//! resists motion in every direction, not only along the surface: where the surface's transfer function
//! is not saturated at the proxy (the proxy sits in its ramp), the point also carries part of the normal
//! load and less is left for tangential friction. Surfaces that should feel friction want a transfer
//! function that reaches its full strength within a few micrometres of depth (a steep ramp).
//!
//! **Vortex core.** A line through the proxy along `w` would only resist sideways motion; to follow a
//! vortex the line is placed on the core estimated from the local linearisation `v(x + d) = v + J d`:
//! with `(a, b)` an orthonormal pair across `w`, solve the 2x2 system for `d` in that plane that zeroes the
//! in-plane velocity (the "reduced velocity" core criterion). For solid-body rotation, and for a Burgers
//! vortex with its radial inflow, this is the exact core. When the 2x2 system is singular the line goes
//! through the proxy.
//!
//! All sampling is allocation-free; so is [`RenderScene::emit`].

mod config;
pub mod limits;
mod mode;
mod scene;
pub mod transfer;

pub use config::{ModeConfig, ModeKind};
pub use limits::{
    DEFAULT_POWER_BUDGET_W, MAX_COORDINATE_M, MAX_FRICTION_MU, MAX_POWER_BUDGET_W, MAX_STRENGTH_N,
    MAX_TRANSFER_VALUE,
};
pub use mode::{Mode, ModeError, SurfaceSide, MAX_MODES, MIN_DIRECTION_MAGNITUDE};
pub use scene::{ModeInput, ModeMemory, RenderScene};
pub use transfer::{TransferError, TransferFunction};

#[cfg(test)]
mod physics_tests;
#[cfg(test)]
mod tests;
