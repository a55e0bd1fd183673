"""Pure models of the rake's drives, motors and arm: the emulator's physics."""
