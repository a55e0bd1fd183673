"""Pure models of the rake's drives, motors and arm: the emulator's physics."""

from drivers.compiled import activate as _activate

# the physics compiled with mypyc, when built for these very sources (drivers.compiled)
_activate(__path__)
