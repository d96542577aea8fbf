"""Shared FMI wrapper machinery of the immersim units (packed into every FMU)."""
from .slave import FmuInputError, FmuModelError, TableSlave
from .variables import Var, markdown_table, vector

__all__ = ["FmuInputError", "FmuModelError", "TableSlave", "Var", "markdown_table", "vector"]
