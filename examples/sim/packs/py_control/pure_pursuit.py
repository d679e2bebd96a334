"""Lane keeping by pure pursuit: steer onto the arc that reaches the lane centre a little way ahead.

The lane comes from `vision.lane_detector` as the centre line y = c0 + c1 x + c2 x² in the vehicle frame
(x forward, y left, metres, from the camera). Pure pursuit (Coulter, 1992) takes the point of that line
`lookahead` metres ahead, the circle through the rear axle tangent to the vehicle's heading and through
that point, and the road-wheel angle that drives it: δ = atan(2 L y / d²), L the wheelbase, d the
distance from the rear axle. The speed is held by a PI loop on throttle and brake.
"""

import math

from kairos_sdk import F64, VECTOR, Component, Descriptor, Property


def _descriptor():
    return (
        Descriptor("pure_pursuit", category="control", label="Pure pursuit lane keeping",
                   doc="Steering, throttle and brake that keep a vehicle on the detected lane's centre at a "
                       "target speed (pure pursuit and a PI speed loop)")
        .input("lane", VECTOR, doc="The lane centre [c0, c1, c2, found] from vision.lane_detector")
        .input("speed", F64, doc="The vehicle's speed, m/s (the newest is used)", policy="last_or_next")
        .output("steering", F64, doc="Road-wheel angle, radians, positive to the left")
        .output("throttle", F64, doc="Accelerator, 0 to 1")
        .output("brake", F64, doc="Brake, 0 to 1")
        .property(Property.f64("target_speed", 15.0).range(0, 60).unit("m/s").live()
                  .doc("The speed to hold"))
        .property(Property.f64("lookahead_time", 0.6).range(0.1, 5).unit("s").live()
                  .doc("How far ahead to aim, in seconds at the current speed"))
        .property(Property.f64("min_lookahead", 6.0).range(1, 50).unit("m").live()
                  .doc("The shortest aim distance (at low speed)"))
        .property(Property.f64("wheelbase", 2.7).range(0.5, 10).unit("m").doc("Front to rear axle"))
        .property(Property.f64("camera_to_rear_axle", 1.5).range(0, 10).unit("m")
                  .doc("How far the camera is ahead of the rear axle"))
        .property(Property.f64("max_steering", 0.5).range(0.05, 1.2).unit("rad").doc("The actuator's limit"))
        .property(Property.f64("speed_gain", 0.25).range(0, 10).live().doc("Throttle per m/s of speed error"))
        .property(Property.f64("speed_integral", 0.05).range(0, 10).live()
                  .doc("Throttle per m of accumulated speed error"))
    )


class PurePursuit(Component):
    descriptor = _descriptor()

    def birth(self, ctx):
        self.speed = 0.0
        self.steering = 0.0
        self.integral = 0.0
        self.last_time = None
        self.lost = 0

    def core(self, ctx):
        lane = ctx.read("lane")
        latest = ctx.try_read("speed")
        while latest is not None:
            self.speed = float(latest.data)
            latest = ctx.try_read("speed")
        c0, c1, c2, found = (float(v) for v in lane.data[:4])
        if found >= 1:
            self.steering = self._steer(ctx, c0, c1, c2)
            self.lost = 0
        else:
            # No lane in sight: keep the last angle, and say so once per second of frames.
            if self.lost % 20 == 0:
                print(f"no lane found at {lane.timestamp / 1e9:.2f} s: keeping the steering angle")
            self.lost += 1
        throttle, brake = self._speed_loop(ctx, lane.timestamp)
        ctx.write_processed("steering", lane, self.steering)
        ctx.write_processed("throttle", lane, throttle)
        ctx.write_processed("brake", lane, brake)

    def _steer(self, ctx, c0, c1, c2):
        lookahead = max(ctx.property("min_lookahead"), ctx.property("lookahead_time") * self.speed)
        lateral = c0 + c1 * lookahead + c2 * lookahead * lookahead
        ahead = lookahead + ctx.property("camera_to_rear_axle")
        distance_sq = ahead * ahead + lateral * lateral
        angle = math.atan(2.0 * ctx.property("wheelbase") * lateral / distance_sq)
        limit = ctx.property("max_steering")
        return max(-limit, min(limit, angle))

    def _speed_loop(self, ctx, now_ns):
        error = ctx.property("target_speed") - self.speed
        if self.last_time is not None:
            dt = max(0.0, min(0.5, (now_ns - self.last_time) * 1e-9))
            self.integral = max(-20.0, min(20.0, self.integral + error * dt))
        self.last_time = now_ns
        command = ctx.property("speed_gain") * error + ctx.property("speed_integral") * self.integral
        if command >= 0.0:
            return min(1.0, command), 0.0
        return 0.0, min(1.0, -command)
