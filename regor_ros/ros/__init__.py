"""rclpy glue around the core: message conversion, parameters and the register node."""
