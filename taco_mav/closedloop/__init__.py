"""Closed loop on a real autopilot: missions flown on ArduPilot Rover SITL and PX4 SITL (SIH) with the daemon in
the loop, started as a user starts it, and scored against the simulator's truth.

One idea a module:

- `ardupilot`: ArduPilot Rover SITL missions (`MissionSpec`, `run_mission`);
- `px4`: PX4 SIH rover missions (`Px4MissionSpec`, `run_px4_mission`), on `px4_sitl` (the PX4 process, its
  ground-station link and flight modes);
- `gcs`: the harness's ground station (commands, parameters, the receive log, mission upload) and the steps
  every mission takes through it (EKF origin, waiting for the EKF, arming, stopping a runaway);
- `scoring`: the figures of a mission (the EKF and our reports against the truth, at the ground station and
  where we sent them) and the bounds they are held to (`accuracy_failures`);
- `faults`: faults on cue during an ArduPilot mission (camera, matcher stall, link cut, receiver glitch, spoof);
- `world`: the synthetic world the daemon's camera sees, centred on the autopilot's home;
- `processes`: the daemon as a user starts it, and stopping a process group;
- `geometry`: local metres about home and the mission's square.

`taco-mav mission` and `tools/sitl_mission.py`, `tools/px4_mission.py` are command lines over it;
`tests/test_sitl.py` and `tests/test_px4.py` fly it when `ARDUROVER` / `PX4_SITL` name the binaries."""
