"""FMI 3.0 test unit (pythonfmu3): first-order lag y' = (u - y)/tau, exact for a held input."""
import math

from pythonfmu3 import Fmi3Causality, Fmi3Slave, Fmi3Variability, Float64


class lag3(Fmi3Slave):
    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.author = "immersim tests"
        self.description = "first-order lag, FMI 3.0"
        self.tau = 0.5
        self.u = 0.0
        self.y = 0.0
        self.register_variable(Float64("time", causality=Fmi3Causality.independent, variability=Fmi3Variability.continuous))
        self.register_variable(Float64("tau", causality=Fmi3Causality.parameter, variability=Fmi3Variability.tunable, start=0.5))
        self.register_variable(Float64("u", causality=Fmi3Causality.input, start=0.0))
        self.register_variable(Float64("y", causality=Fmi3Causality.output))
        self.time = 0.0

    def do_step(self, current_time, step_size):
        a = math.exp(-step_size / self.tau)
        self.y = self.u + (self.y - self.u) * a
        self.time = current_time + step_size
        return True
