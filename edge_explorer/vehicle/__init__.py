"""The vehicle and its sensors as models, shared by the daemon, the planners, the mapping and the simulator: the
action table and motion model (:mod:`~edge_explorer.vehicle.dynamics`), the depth camera's intrinsics, pose and
noise (:mod:`~edge_explorer.vehicle.camera`) and the planar range sensor the planners score views with
(:mod:`~edge_explorer.vehicle.sensor`). Pure models: nothing here simulates a world or talks to an autopilot."""
