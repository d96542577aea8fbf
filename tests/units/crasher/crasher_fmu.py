"""Test unit that crashes the process it runs in at a chosen time (``how = "segv"``: a read
of address 0 through ctypes; ``"abort"``: ``os.abort()``), to test that a run survives the
crash of a unit: one line naming the unit and the time, and a complete log.

Its output ``y`` is the time at the end of each step, so the log tells which steps completed.
"""
import ctypes
import os

from immersim.fmus.common import TableSlave, Var


class crasher(TableSlave):
    modelName = "crasher"
    description = "crashes the process at time crash_at"
    VARIABLES = (
        Var("crash_at", "parameter", "Real", 1e9, "s", "simulation time of the crash"),
        Var("how", "parameter", "String", "segv", "", "segv (read of address 0) or abort"),
        Var("u", "input", "Real", 0.0, "", "any input (unused)"),
        Var("y", "output", "Real", 0.0, "s", "time at the end of the last step"),
    )

    def setup_model(self):
        self.values["y"] = 0.0

    def step_model(self, t, h):
        if t + h >= self.values["crash_at"] - 1e-9:
            if self.values["how"] == "abort":
                os.abort()
            ctypes.string_at(0)
        self.values["y"] = t + h
