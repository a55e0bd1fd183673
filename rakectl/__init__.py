"""rakectl: impedance control of a demining rake robot.

The pure core (kinematics, impedance filter, estimator, discretization) imports
no I/O libraries; the CLI is the composition root that reads files.
"""

__version__ = "0.1.0"
