"""Drivers: a clock, a transport and a plant around N onboard stacks.

- :mod:`.world`: the simulated world (simulated clock, lossy simulated link, N simulated plants,
  one compiled call per tick);
- :mod:`.node`: one UAV in real time over a network (Zenoh), its plant simulated;
  :mod:`.swarm`: a scenario as one node process per UAV;
- :mod:`.flight`: one UAV alone, closed loop.
"""
