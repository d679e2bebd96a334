"""A Gymnasium environment as a component: a simulator from PyPI, stepped once per tick by the diagram.

Gymnasium (the maintained successor of OpenAI Gym, `pip install gymnasium`) holds dozens of simulated
systems behind one interface: `reset()`, then `step(action)` → observation, reward, terminated, truncated.
This component steps one of them at `rate` ticks a second with the newest action the diagram sent, and
writes what it observes. Each sample carries both times: its timestamp is the runtime clock's, and
`sim_time` is the environment's own time (steps × `step_seconds`), so a recording shows how the two relate.
"""

from kairos_sdk import ANY, F64, TEXT, VECTOR, Component, Descriptor, Property


def _descriptor():
    return (
        Descriptor("environment", category="simulation", label="Gymnasium environment",
                   doc="A Gymnasium environment (pip install gymnasium) stepped at each tick with the newest "
                       "action; its observation, reward and episode ends as outputs")
        .periodic()
        .input("action", ANY, doc="The action: a number, or a vector for several (held between ticks)",
               policy="last_or_next")
        .output("observation", VECTOR, doc="What the environment observes after the step")
        .output("reward", F64, doc="The step's reward")
        .output("sim_time", F64, doc="The environment's time: steps since its start × step_seconds")
        .output("episode", TEXT, doc="Each episode's end: its number, steps, return and why it ended")
        .property(Property.text("environment", "MountainCarContinuous-v0")
                  .doc("The Gymnasium environment's id (its action space must be a Box)"))
        .property(Property.f64("rate", 30.0).range(0.1, 1000).unit("Hz").doc("Steps per second"))
        .property(Property.f64("step_seconds", 0.0).range(0, 60).unit("s")
                  .doc("The environment's time per step; 0: one tick's (1 / rate)"))
        .property(Property.i64("seed", 0).doc("Seed of the first reset: the same seed, the same episodes"))
    )


class Environment(Component):
    descriptor = _descriptor()

    def birth(self, ctx):
        try:
            import gymnasium
            import numpy
        except ImportError:
            raise ImportError("py_gym.environment needs Gymnasium: pip install gymnasium into the "
                              "interpreter that runs this pack") from None
        self.numpy = numpy
        name = ctx.property("environment")
        try:
            self.env = gymnasium.make(name)
        except gymnasium.error.Error as error:
            raise ValueError(f"property 'environment': {error}") from None
        space = self.env.action_space
        if not isinstance(space, gymnasium.spaces.Box):
            raise ValueError(f"property 'environment': {name} takes {space}, not a Box of numbers")
        self.low, self.high, self.shape = space.low, space.high, space.shape
        self.action = numpy.zeros(self.shape, dtype=space.dtype)
        rate = ctx.property("rate")
        ctx.set_frequency(rate)
        self.step_seconds = ctx.property("step_seconds") or 1.0 / rate
        self.observation, _ = self.env.reset(seed=ctx.property("seed"))
        self.steps = 0
        self.episode = 1
        self.episode_steps = 0
        self.episode_return = 0.0

    def core(self, ctx):
        latest = ctx.try_read("action")
        if latest is not None:
            values = self.numpy.asarray(latest.data, dtype=self.action.dtype).reshape(-1)
            if values.size != self.action.size:
                raise ValueError(f"input 'action': {values.size} numbers, the environment takes "
                                 f"{self.action.size}")
            self.action = self.numpy.clip(values.reshape(self.shape), self.low, self.high)
        observation, reward, terminated, truncated, _ = self.env.step(self.action)
        self.steps += 1
        self.episode_steps += 1
        self.episode_return += float(reward)
        now = ctx.now()
        ctx.write("observation", self.numpy.asarray(observation, dtype=float).reshape(-1), now)
        ctx.write("reward", float(reward), now)
        ctx.write("sim_time", self.steps * self.step_seconds, now)
        if terminated or truncated:
            why = "terminated (goal reached)" if terminated else "truncated (time limit)"
            line = (f"episode {self.episode}: {self.episode_steps} steps, return {self.episode_return:.1f}, "
                    f"{why}")
            print(line)
            ctx.write("episode", line, now)
            self.env.reset()
            self.episode += 1
            self.episode_steps = 0
            self.episode_return = 0.0

    def death(self, ctx):
        self.env.close()
