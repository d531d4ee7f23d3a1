"""What runs on the bus: each feature takes its collaborators in its constructor and has `start()` / `async stop()`."""
