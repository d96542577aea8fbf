"""Test unit: one mass of a two-mass, three-spring chain, exact within a step.

Mass ``m`` at position ``x`` is tied to the wall by spring ``k`` and to the other mass (input
``x_other``) by spring ``kc``. For a constant ``x_other`` over a step the motion is exact:
``x(t) = x_eq + (x0 - x_eq) cos(w t) + v0/w sin(w t)`` with ``w = sqrt((k + kc)/m)`` and
``x_eq = kc x_other / (k + kc)``, so every co-simulation error comes from the coupling.
"""
import math

from immersim.fmus.common import TableSlave, Var


class oscillator(TableSlave):
    modelName = "oscillator"
    description = "mass on a wall spring, coupled by spring kc to another mass"
    CAN_HANDLE_STATE = True
    VARIABLES = (
        Var("m", "parameter", "Real", 1.0, "kg", "mass"),
        Var("k", "parameter", "Real", 1.0, "N/m", "wall spring stiffness"),
        Var("kc", "parameter", "Real", 1.0, "N/m", "coupling spring stiffness"),
        Var("x0", "parameter", "Real", 0.0, "m", "initial position"),
        Var("x_other", "input", "Real", 0.0, "m", "position of the coupled mass"),
        Var("x", "output", "Real", 0.0, "m", "position"),
        Var("v", "output", "Real", 0.0, "m/s", "velocity"),
        Var("f_coupling", "output", "Real", 0.0, "N", "force of the coupling spring on this mass"),
        Var("at_rest", "output", "Boolean", True, "", "at the equilibrium of the held input, v = 0"),
    )

    def setup_model(self):
        val = self.values
        if val["m"] <= 0:
            raise ValueError(f"{self.instance_name}: parameter m = {val['m']} must be > 0")
        val["x"], val["v"] = val["x0"], 0.0
        val["f_coupling"] = -val["kc"] * (val["x"] - val["x_other"])
        self._update_rest()

    def _update_rest(self):
        val = self.values
        x_eq = val["kc"] * val["x_other"] / (val["k"] + val["kc"])
        val["at_rest"] = val["v"] == 0.0 and val["x"] == x_eq

    def step_model(self, t, h):
        val = self.values
        m, k, kc, xo = val["m"], val["k"], val["kc"], val["x_other"]
        w = math.sqrt((k + kc) / m)
        x_eq = kc * xo / (k + kc)
        dx, v = val["x"] - x_eq, val["v"]
        c, s = math.cos(w * h), math.sin(w * h)
        val["x"] = x_eq + dx * c + v / w * s
        val["v"] = -dx * w * s + v * c
        val["f_coupling"] = -kc * (val["x"] - xo)
        self._update_rest()

    def get_model_state(self):
        return None

    def set_model_state(self, state):
        pass
