//! Closed-loop simulation: a vehicle that a diagram drives, on a road that the simulated sensors see.
//!
//! Pack `sim`, registered by [`register`]. RTMaps' users test control algorithms against a simulator
//! that "will simulate not only the sensor data streams but also the dynamics of the system, and which
//! can receive commands and react to them"; `sim.vehicle` is that simulator, and porting a diagram to
//! a car means swapping it (and the CAN decoder before it) for the car's CAN interface.
//!
//! | Component | Inputs | Outputs |
//! |---|---|---|
//! | [`sim.vehicle`](vehicle::SimVehicle) | `steering`, `throttle`, `brake` (held) | `world` (`sim_world`), `pose`, `speed`, `lateral_error`, `state` |
//!
//! Modules: [`road`] (the road's geometry), [`dynamics`] (the vehicle's), [`vehicle`] (the component).

#![warn(missing_docs)]

pub mod dynamics;
pub mod road;
pub mod vehicle;

use kairos_sdk::Registry;

/// The pack's name.
pub const PACK_NAME: &str = "sim";

/// Registers the `sim` pack and its component.
pub fn register(registry: &mut Registry) {
    registry
        .pack(PACK_NAME, env!("CARGO_PKG_VERSION"), "built-in")
        .component_described::<vehicle::SimVehicle>(vehicle::descriptor().build(), vehicle::describe)
        .custom_type(kairos_pack_sensors::world::TYPE_NAME);
}
