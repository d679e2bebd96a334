//! `sim.vehicle`: a simulated car on a simulated road, driven by steering, throttle and brake.
//!
//! Each tick it reads the newest commands, advances its [`dynamics`](crate::dynamics) to the tick's
//! time in 1 ms steps, finds itself on the [`road`](crate::road), and writes what it is: its pose and
//! speed, its lateral error from its lane's centre, and the `sim_world` view that the `sensors` pack's
//! camera, lidar, GNSS and IMU render from. As the diagram's clock source it keeps the simulated time
//! (`time_scale` 0: as fast as the diagram runs; 1: real time).

use std::collections::BTreeMap;

use glam::{DQuat, DVec3};
use kairos_pack_sensors::geo::GeoPoint;
use kairos_pack_sensors::trajectory::{GRAVITY, VehicleState};
use kairos_pack_sensors::world::{self, Obstacle, RoadPoint, WorldView};
use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    Component, ComponentError, ComponentInfo, ComponentResult, Context, DataType, DescribeError,
    ExecutionMode, Payload, Pose, ReaderPolicy, Timestamp, TypeFilter, Value,
};

use crate::dynamics::{Commands, Vehicle, VehicleParameters};
use crate::road::{DEFAULT_ROAD, Road};

/// The component's type name.
pub const TYPE_NAME: &str = "sim.vehicle";

/// Integration step, seconds.
const STEP_S: f64 = 0.001;
/// A tick further than this after the last one (a pause) is not integrated: the world waited. Shorter
/// gaps (ticks missed on a busy machine) are, so that the vehicle keeps the clock's time.
const LONGEST_TICK_S: f64 = 1.0;
/// The road the world view holds: this far behind and ahead of the vehicle, metres.
const VIEW_BEHIND_M: f64 = 20.0;
const VIEW_AHEAD_M: f64 = 250.0;
/// Spacing of the road points in the world view, metres.
const VIEW_STEP_M: f64 = 2.0;
/// Obstacles farther than this are left out of the world view, metres.
const OBSTACLE_RANGE_M: f64 = 200.0;
/// The vehicle's footprint, metres: for lane departures and collisions.
const HALF_WIDTH_M: f64 = 0.9;
const FRONT_OVERHANG_M: f64 = 2.0;
const REAR_OVERHANG_M: f64 = 2.5;
/// 2026-01-01T00:00:00Z: where simulated time starts unless told otherwise, so that runs stamp alike.
const DEFAULT_START_TIME: f64 = 1_767_225_600.0;
/// Parked cars on the right shoulder, for the camera and lidar to see.
const DEFAULT_OBSTACLES: &str = "260 -5.2; 610 -5.2; 980 -5.2";

/// The descriptor of `sim.vehicle`.
pub fn descriptor() -> Descriptor {
    let input = |descriptor: Descriptor, name: &str, doc: &str| {
        descriptor.input_with_policy(
            name,
            TypeFilter::OneOf(vec![DataType::F64, DataType::I64, DataType::Bool]),
            ReaderPolicy::LastOrNext,
            doc,
        )
    };
    let base = Descriptor::new(
        TYPE_NAME,
        "simulation",
        "A simulated car on a simulated two-lane road: kinematic at low speed, dynamic with tyre limits at \
         speed, engine power, brakes and actuator delays; driven by steering, throttle and brake (held \
         between ticks); its world view feeds the sensors pack's camera, lidar, GNSS and IMU. As the clock \
         source it keeps simulated time",
    )
    .label("Simulated vehicle")
    .mode(ExecutionMode::Periodic)
    .simulated_time()
    .holds_inputs();
    let base = input(
        base,
        "steering",
        "Road-wheel angle, radians, positive to the left (held)",
    );
    let base = input(base, "throttle", "Accelerator, 0 to 1 (held)");
    input(base, "brake", "Brake, 0 to 1 (held)")
        .output(
            "world",
            world::data_type(),
            "What the simulated sensors see: the vehicle, its road and obstacles (connect to their `vehicle`)",
        )
        .output("pose", DataType::Pose, "Position (east, north, up, metres) and orientation")
        .output("speed", DataType::F64, "Speed over the ground, m/s")
        .output(
            "lateral_error",
            DataType::F64,
            "Metres from the centre of the lane, positive to the left",
        )
        .output(
            "state",
            DataType::Vector,
            "station m, lateral error m, heading error rad, speed m/s, yaw rate rad/s, steering rad, road \
             curvature 1/m",
        )
        .property(
            Property::f64("rate", 100.0)
                .unit("Hz")
                .range(10.0, 1000.0)
                .doc("Steps per second: commands are read and outputs written at this rate"),
        )
        .property(
            Property::f64("time_scale", 1.0).range(0.0, 1000.0).doc(
                "As the clock source: simulated seconds per real second (1: real time; 0: as fast as \
                 the diagram runs, for a sequential diagram)",
            ),
        )
        .property(
            Property::f64("start_time", DEFAULT_START_TIME)
                .unit("s")
                .doc("As the clock source: the simulated time at the start, seconds since 1970 (UTC)"),
        )
        .property(
            Property::f64("duration", 0.0)
                .unit("s")
                .range(0.0, 1e7)
                .doc("Simulated seconds after which the simulation ends (0: never)"),
        )
        .property(Property::text("road", DEFAULT_ROAD).doc(
            "The road: 'straight LENGTH', 'left RADIUS ANGLE', 'right RADIUS ANGLE' (metres, degrees), \
             separated by ';'",
        ))
        .property(
            Property::f64("transition", 30.0)
                .unit("m")
                .range(0.0, 500.0)
                .doc("Length of the clothoids joining straights and curves"),
        )
        .property(
            Property::f64("lane_width", 3.5)
                .unit("m")
                .range(2.0, 6.0)
                .doc("Width of each of the two lanes; the vehicle starts in the right one"),
        )
        .property(Property::text("obstacles", DEFAULT_OBSTACLES).doc(
            "Boxes on or beside the road: 'STATION LATERAL [LENGTH WIDTH HEIGHT]' (metres along the road, \
             left of its centre line), separated by ';'",
        ))
        .property(Property::f64("initial_speed", 0.0).unit("m/s").range(0.0, 70.0).doc("Speed at the start"))
        .property(Property::f64("latitude", 48.7167).unit("deg").range(-90.0, 90.0).doc("The world origin's latitude"))
        .property(
            Property::f64("longitude", 2.2333)
                .unit("deg")
                .range(-180.0, 180.0)
                .doc("The world origin's longitude"),
        )
        .property(Property::f64("altitude", 150.0).unit("m").doc("The world origin's height above the WGS84 ellipsoid"))
        .property(Property::f64("mass", 1500.0).unit("kg").range(100.0, 50_000.0).doc("Mass"))
        .property(
            Property::f64("max_steering", 0.5)
                .unit("rad")
                .range(0.05, 1.2)
                .doc("Largest road-wheel angle"),
        )
        .property(
            Property::f64("steering_rate", 0.6)
                .unit("rad/s")
                .range(0.01, 10.0)
                .doc("Fastest change of the road-wheel angle"),
        )
        .property(
            Property::f64("actuator_delay", 0.05)
                .unit("s")
                .range(0.0, 2.0)
                .doc("Delay between a command's arrival and the actuators following it"),
        )
        .property(
            Property::f64("friction", 0.9)
                .range(0.05, 1.5)
                .doc("Tyre-road friction coefficient (0.9 dry asphalt, 0.5 wet, 0.1 ice)"),
        )
        .property(Property::f64("max_power", 90.0).unit("kW").range(1.0, 2000.0).doc("Largest power at the wheels"))
}

/// One obstacle as written: metres along the road, left of its centre line, and its size.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlacedObstacle {
    /// Metres along the road.
    pub station_m: f64,
    /// Metres left of the centre line.
    pub lateral_m: f64,
    /// Length, width, height, metres.
    pub size: (f64, f64, f64),
}

/// Why the `obstacles` property does not read: the obstacle (1-based) and its text.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ObstacleError {
    /// Words that are not finite numbers.
    #[error("obstacle {index} ('{part}') is not numbers")]
    NotNumbers {
        /// Which obstacle, from 1.
        index: usize,
        /// Its text.
        part: String,
    },
    /// Neither a place alone nor a place and a positive size.
    #[error(
        "obstacle {index} ('{part}') is not 'STATION LATERAL' or 'STATION LATERAL LENGTH WIDTH HEIGHT' with a positive size"
    )]
    Shape {
        /// Which obstacle, from 1.
        index: usize,
        /// Its text.
        part: String,
    },
}

/// Parses the `obstacles` property.
///
/// # Errors
///
/// An obstacle that does not read, with its number.
pub fn parse_obstacles(text: &str) -> Result<Vec<PlacedObstacle>, ObstacleError> {
    let mut found = Vec::new();
    for (index, part) in text
        .split([';', '\n'])
        .map(str::trim)
        .filter(|p| !p.is_empty())
        .enumerate()
    {
        let numbers: Result<Vec<f64>, _> = part.split_whitespace().map(str::parse::<f64>).collect();
        let numbers = numbers
            .ok()
            .filter(|n| n.iter().all(|v| v.is_finite()))
            .ok_or_else(|| ObstacleError::NotNumbers {
                index: index + 1,
                part: part.to_owned(),
            })?;
        let size = match numbers.as_slice() {
            [_, _] => (4.5, 1.8, 1.5),
            [_, _, length, width, height] if *length > 0.0 && *width > 0.0 && *height > 0.0 => {
                (*length, *width, *height)
            }
            _ => {
                return Err(ObstacleError::Shape {
                    index: index + 1,
                    part: part.to_owned(),
                });
            }
        };
        let (Some(&station_m), Some(&lateral_m)) = (numbers.first(), numbers.get(1)) else {
            continue;
        };
        found.push(PlacedObstacle {
            station_m,
            lateral_m,
            size,
        });
    }
    Ok(found)
}

/// Checks the road and obstacles when the diagram is checked, so that a typo is reported on its
/// property before anything runs.
///
/// # Errors
///
/// The property that does not read, with what is wrong.
pub fn describe(properties: &BTreeMap<String, Value>) -> Result<ComponentInfo, DescribeError> {
    let text = |name: &str, default: &str| {
        properties
            .get(name)
            .and_then(Value::as_text)
            .unwrap_or(default)
            .to_owned()
    };
    crate::road::parse_segments(&text("road", DEFAULT_ROAD)).map_err(|e| {
        DescribeError::property("road", e.to_string())
            .with_suggestion("e.g. 'straight 100; left 200 45; straight 50'")
    })?;
    parse_obstacles(&text("obstacles", DEFAULT_OBSTACLES)).map_err(|e| {
        DescribeError::property("obstacles", e.to_string())
            .with_suggestion("e.g. '250 -5.2; 600 1.75 4.5 1.8 1.5'")
    })?;
    Ok(descriptor().build())
}

/// The `sim.vehicle` component. See [`descriptor`].
#[derive(Debug, Default)]
pub struct SimVehicle {
    road: Option<Road>,
    vehicle: Option<Vehicle>,
    obstacles: Vec<PlacedObstacle>,
    origin: Option<GeoPoint>,
    lane_width: f64,
    duration_s: f64,
    commands: Commands,
    last_tick: Option<Timestamp>,
    road_hint: usize,
    /// Simulated seconds driven.
    time_s: f64,
    departures: u64,
    departed: bool,
    collisions: u64,
    colliding: bool,
    squared_error_sum: f64,
    error_samples: u64,
    /// Station, lateral error and speed at the last tick, for the status.
    last_state: Option<(f64, f64, f64)>,
}

/// A number from a command input: floats as they are, integers and booleans as numbers.
fn number(payload: &Payload, input: &str) -> Result<f64, ComponentError> {
    match payload {
        Payload::F64(v) => Ok(*v),
        #[allow(clippy::cast_precision_loss, reason = "a command's value")]
        Payload::I64(v) => Ok(*v as f64),
        Payload::Bool(v) => Ok(f64::from(u8::from(*v))),
        other => Err(ComponentError::failed(format_args!(
            "input '{input}': expected a number, got {}",
            other.data_type()
        ))),
    }
}

impl SimVehicle {
    /// Reads the newest value of each command input; an unconnected or silent one keeps its value.
    fn read_commands(&mut self, ctx: &mut Context) -> ComponentResult {
        for (input, slot) in [
            ("steering", &mut self.commands.steering),
            ("throttle", &mut self.commands.throttle),
            ("brake", &mut self.commands.brake),
        ] {
            if let Some(sample) = ctx.try_read(input)? {
                let value = number(&sample.payload, input)?;
                if value.is_finite() {
                    *slot = value;
                }
            }
        }
        Ok(())
    }

    /// The world view at this tick, with the vehicle located on its road.
    fn view(&mut self, located: &crate::road::Located) -> Option<WorldView> {
        let (road, vehicle, origin) = (self.road.as_ref()?, self.vehicle.as_ref()?, self.origin?);
        let s = vehicle.state;
        let (sin, cos) = s.yaw.sin_cos();
        let to_vehicle = |x: f64, y: f64| {
            let (dx, dy) = (x - s.x, y - s.y);
            (cos * dx + sin * dy, -sin * dx + cos * dy)
        };
        let first = (located.station_m - VIEW_BEHIND_M).max(0.0);
        let count = ((VIEW_AHEAD_M + VIEW_BEHIND_M) / VIEW_STEP_M) as usize;
        let road_points: Vec<RoadPoint> = (0..=count)
            .map(|i| road.at(first + i as f64 * VIEW_STEP_M))
            .map(|sample| {
                let (x, y) = to_vehicle(sample.x, sample.y);
                RoadPoint {
                    x,
                    y,
                    station_m: sample.station_m,
                }
            })
            .collect();
        let obstacles: Vec<Obstacle> = self
            .obstacles
            .iter()
            .filter(|o| (o.station_m - located.station_m).abs() < OBSTACLE_RANGE_M)
            .map(|o| {
                let centre = road.at(o.station_m);
                let (east, north) = (
                    centre.x - centre.heading.sin() * o.lateral_m,
                    centre.y + centre.heading.cos() * o.lateral_m,
                );
                let (x, y) = to_vehicle(east, north);
                Obstacle {
                    x,
                    y,
                    yaw: centre.heading - s.yaw,
                    length: o.size.0,
                    width: o.size.1,
                    height: o.size.2,
                }
            })
            .collect();
        let (ax, ay) = s.acceleration;
        let velocity = DVec3::new(s.vx * cos - s.vy * sin, s.vx * sin + s.vy * cos, 0.0);
        let acceleration = DVec3::new(ax * cos - ay * sin, ax * sin + ay * cos, 0.0);
        let state = VehicleState {
            time_s: self.time_s,
            position: DVec3::new(s.x, s.y, 0.0),
            velocity,
            acceleration,
            yaw: s.yaw,
            yaw_rate: s.yaw_rate,
            pitch: 0.0,
            pitch_rate: 0.0,
            orientation: DQuat::from_rotation_z(s.yaw),
            angular_velocity_body: DVec3::new(0.0, 0.0, s.yaw_rate),
            specific_force_body: DVec3::new(ax, ay, GRAVITY),
        };
        Some(WorldView {
            state,
            origin,
            station_m: located.station_m,
            lane_width_m: self.lane_width,
            road: road_points,
            obstacles,
        })
    }

    /// Counts lane departures and collisions (each once, when it starts) and says so in the log.
    fn watch(&mut self, ctx: &Context, lateral_error: f64, view: &WorldView) {
        let departed = lateral_error.abs() > 0.5 * self.lane_width - HALF_WIDTH_M;
        if departed && !self.departed {
            self.departures += 1;
            tracing::warn!(
                component = ctx.id(),
                "lane departure at {:.1} s, {:.0} m along the road: {:+.2} m from the lane centre",
                self.time_s,
                view.station_m,
                lateral_error
            );
        }
        self.departed = departed;
        let colliding = view.obstacles.iter().any(|o| {
            // The vehicle's footprint against the box, taken as aligned with the vehicle: exact for
            // obstacles along the road, which is how they are placed.
            o.x - 0.5 * o.length < FRONT_OVERHANG_M
                && o.x + 0.5 * o.length > -REAR_OVERHANG_M
                && o.y.abs() < 0.5 * o.width + HALF_WIDTH_M
        });
        if colliding && !self.colliding {
            self.collisions += 1;
            tracing::warn!(
                component = ctx.id(),
                "collision at {:.1} s, {:.0} m along the road",
                self.time_s,
                view.station_m
            );
        }
        self.colliding = colliding;
    }
}

impl Component for SimVehicle {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        let property = |e: &dyn std::fmt::Display, name: &str| {
            ComponentError::failed(format_args!("property '{name}': {e}"))
        };
        let transition = ctx.f64_property("transition")?;
        let road = Road::parse(&ctx.text_property("road")?, transition).map_err(|e| property(&e, "road"))?;
        self.obstacles =
            parse_obstacles(&ctx.text_property("obstacles")?).map_err(|e| property(&e, "obstacles"))?;
        self.lane_width = ctx.f64_property("lane_width")?;
        self.duration_s = ctx.f64_property("duration")?;
        self.origin = Some(GeoPoint::new(
            ctx.f64_property("latitude")?,
            ctx.f64_property("longitude")?,
            ctx.f64_property("altitude")?,
        ));
        let parameters = VehicleParameters {
            mass_kg: ctx.f64_property("mass")?,
            max_steering: ctx.f64_property("max_steering")?,
            steering_rate: ctx.f64_property("steering_rate")?,
            actuator_delay_s: ctx.f64_property("actuator_delay")?,
            friction: ctx.f64_property("friction")?,
            max_power: ctx.f64_property("max_power")? * 1000.0,
            ..VehicleParameters::default()
        };
        // In the right lane's centre, along the road.
        let start = road.at(0.0);
        let lateral = -0.5 * self.lane_width;
        self.vehicle = Some(Vehicle::new(
            parameters,
            start.x - start.heading.sin() * lateral,
            start.y + start.heading.cos() * lateral,
            start.heading,
            ctx.f64_property("initial_speed")?,
        ));
        tracing::info!(component = ctx.id(), "road: {}", road.summary());
        self.road = Some(road);
        ctx.set_frequency(ctx.f64_property("rate")?);
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let now = ctx.now();
        self.read_commands(ctx)?;
        let elapsed = self
            .last_tick
            .map_or(0.0, |last| now.nanos_since(last) as f64 * 1e-9);
        self.last_tick = Some(now);
        let Some(vehicle) = self.vehicle.as_mut() else {
            return Err(ComponentError::failed("the vehicle was not born"));
        };
        if (0.0..=LONGEST_TICK_S).contains(&elapsed) {
            vehicle.advance(elapsed, STEP_S);
            self.time_s += elapsed;
        }
        vehicle.command(self.commands);
        let state = vehicle.state;
        let speed = vehicle.speed();
        let Some(road) = self.road.as_ref() else {
            return Err(ComponentError::failed("the vehicle has no road"));
        };
        let Some(located) = road.locate(state.x, state.y, self.road_hint) else {
            tracing::warn!(
                component = ctx.id(),
                "the vehicle left the road's ends: the simulation ends"
            );
            return Err(ComponentError::EndOfStream);
        };
        self.road_hint = located.index;
        let lateral_error = located.lateral_m + 0.5 * self.lane_width;
        let heading_error = (state.yaw - located.heading + std::f64::consts::PI)
            .rem_euclid(std::f64::consts::TAU)
            - std::f64::consts::PI;
        let Some(view) = self.view(&located) else {
            return Err(ComponentError::failed("the vehicle was not born"));
        };
        self.watch(ctx, lateral_error, &view);
        self.squared_error_sum += lateral_error * lateral_error;
        self.error_samples += 1;
        self.last_state = Some((located.station_m, lateral_error, speed));
        let pose = Pose {
            position: view.state.position,
            orientation: view.state.orientation,
        };
        ctx.write_at("world", view.payload(), now)?;
        ctx.write_at("pose", Payload::Pose(pose), now)?;
        ctx.write_at("speed", Payload::F64(speed), now)?;
        ctx.write_at("lateral_error", Payload::F64(lateral_error), now)?;
        let summary = vec![
            located.station_m,
            lateral_error,
            heading_error,
            speed,
            state.yaw_rate,
            state.steering,
            located.curvature,
        ];
        ctx.write_at("state", Payload::Vector(summary.into()), now)?;
        if self.duration_s > 0.0 && self.time_s >= self.duration_s - 1e-9 {
            tracing::info!(
                component = ctx.id(),
                "simulation over after {:.1} s: {:.0} m driven, lateral error RMS {:.3} m, {} lane departures, {} collisions",
                self.time_s,
                located.station_m,
                self.lateral_rms(),
                self.departures,
                self.collisions
            );
            return Err(ComponentError::EndOfStream);
        }
        Ok(())
    }

    fn status(&self) -> Option<serde_json::Value> {
        let (station, lateral, speed) = self.last_state.unwrap_or_default();
        Some(serde_json::json!({
            "kind": "simulation",
            "time_s": (self.time_s * 1000.0).round() / 1000.0,
            "station_m": (station * 10.0).round() / 10.0,
            "lateral_error_m": (lateral * 1000.0).round() / 1000.0,
            "lateral_error_rms_m": (self.lateral_rms() * 1000.0).round() / 1000.0,
            "speed_kmh": (speed * 36.0).round() / 10.0,
            "lane_departures": self.departures,
            "collisions": self.collisions,
        }))
    }

    fn property_changed(&mut self, _name: &str, _value: &Value, _ctx: &mut Context) -> ComponentResult {
        Ok(())
    }
}

impl SimVehicle {
    /// The root mean square of the lateral error so far, metres.
    fn lateral_rms(&self) -> f64 {
        if self.error_samples == 0 {
            0.0
        } else {
            (self.squared_error_sum / self.error_samples as f64).sqrt()
        }
    }
}

#[cfg(test)]
mod tests {
    use kairos_sdk::harness::Harness;

    use super::*;

    fn harness(properties: &[(&str, Value)]) -> Harness {
        let mut harness = Harness::new(descriptor().build(), SimVehicle::default());
        for (name, value) in properties {
            harness.set_property(name, value.clone()).expect("property");
        }
        harness
    }

    #[test]
    fn with_no_commands_it_stands_in_its_lane_and_the_sensors_get_its_world() {
        let out = harness(&[]).run_periodic(50).expect("runs");
        let worlds = out.samples("world");
        assert_eq!(worlds.len(), 50);
        let last = WorldView::from_payload(&worlds[49].payload).expect("a world");
        assert!(last.state.speed() < 1e-9);
        assert!((last.state.specific_force_body.z - GRAVITY).abs() < 1e-9);
        // The road's centre line is 1.75 m to the vehicle's left, straight ahead.
        let (left, station) = last.centre_line_at(30.0).expect("road ahead");
        assert!((left - 1.75).abs() < 1e-6, "{left}");
        assert!((station - 30.0).abs() < 1e-6);
        let errors = out.samples("lateral_error");
        assert!(matches!(errors[49].payload, Payload::F64(e) if e.abs() < 1e-9));
    }

    #[test]
    fn it_drives_with_throttle_and_steers_out_of_its_lane() {
        let mut harness = harness(&[("initial_speed", Value::F64(10.0))]);
        for tick in 0..300 {
            let at = Timestamp::from_millis(tick * 10);
            harness.push("throttle", Payload::F64(0.2), at);
            harness.push("steering", Payload::F64(0.02), at);
        }
        let out = harness.run_periodic(300).expect("runs");
        let speeds = out.samples("speed");
        let Payload::F64(speed) = speeds[299].payload else {
            panic!("speed")
        };
        assert!(speed > 10.0, "accelerates: {speed}");
        let Payload::F64(error) = out.samples("lateral_error")[299].payload else {
            panic!("error")
        };
        assert!(error > 0.9, "steered left, out of the lane: {error}");
    }

    #[test]
    fn bad_roads_and_obstacles_are_refused_on_their_property() {
        let mut properties = BTreeMap::new();
        properties.insert("road".to_owned(), Value::Text("straight 100; left 50".to_owned()));
        let error = describe(&properties).expect_err("bad road");
        assert_eq!(error.property.as_deref(), Some("road"));
        assert!(error.message.contains("segment 2"), "{}", error.message);
        properties.clear();
        properties.insert("obstacles".to_owned(), Value::Text("100 x".to_owned()));
        let error = describe(&properties).expect_err("bad obstacle");
        assert_eq!(error.property.as_deref(), Some("obstacles"));
        assert!(describe(&BTreeMap::new()).is_ok());
        let parsed = parse_obstacles("10 2; 20 -3 4 2 1").expect("reads");
        assert_eq!(parsed[1].size, (4.0, 2.0, 1.0));
    }
}
