"""Shared FMI wrapper machinery of the immersim units (packed into every FMU)."""
from .options import BuildOption, build_options, options_table
from .slave import OUTPUTS_UNCHANGED, FmuInputError, FmuModelError, TableSlave
from .variables import Var, markdown_table, vector

__all__ = ["BuildOption", "OUTPUTS_UNCHANGED", "FmuInputError", "FmuModelError", "TableSlave", "Var", "build_options",
           "markdown_table", "options_table", "vector"]
