"""Shared FMI wrapper machinery of the immersim units (packed into every FMU)."""
from .slave import OUTPUTS_UNCHANGED, FmuInputError, FmuModelError, TableSlave
from .variables import Var, markdown_table, vector

__all__ = ["OUTPUTS_UNCHANGED", "FmuInputError", "FmuModelError", "TableSlave", "Var", "markdown_table", "vector"]
