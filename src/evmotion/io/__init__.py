"""Reading and writing events, frames, IMU and flow in every common format."""
