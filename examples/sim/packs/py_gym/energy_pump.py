"""The mountain car's textbook policy: push the way the car moves, so each swing climbs higher."""

from kairos_sdk import F64, VECTOR, Component, Descriptor


class EnergyPump(Component):
    descriptor = (
        Descriptor("energy_pump", category="control", label="Mountain car energy pump",
                   doc="Full force in the direction of motion: the mountain car reaches the hilltop by "
                       "swinging")
        .input("observation", VECTOR, doc="Position and velocity (MountainCarContinuous-v0)")
        .output("action", F64, doc="The force, -1 or 1")
    )

    def core(self, ctx):
        sample = ctx.read("observation")
        velocity = float(sample.data[1])
        ctx.write_processed("action", sample, 1.0 if velocity >= 0.0 else -1.0)
