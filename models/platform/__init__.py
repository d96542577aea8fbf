"""PSS 3-2-1 six-DOF motion platform (thesis ch. 6): kinematics, Lagrangian dynamics, control,
motion cueing and integrators. See ``fmus/platform/README.md`` for the equations."""
from .kinematics import (OutsideWorkspaceError, SingularityError, actuator_jacobian, forward_kinematics,
                         inverse_kinematics, rotation, workspace_check)
from .params import PlatformParams

__all__ = ["OutsideWorkspaceError", "PlatformParams", "SingularityError", "actuator_jacobian",
           "forward_kinematics", "inverse_kinematics", "rotation", "workspace_check"]
