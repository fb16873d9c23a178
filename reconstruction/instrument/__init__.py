"""The bench model that acquisition and the simulator share: the motion-time model and the instrument's optics."""
