"""A print farm on one machine for the farm tests and `bench/farm.py`.

- `fleet.py`: the printers (what each has loaded, its volume) and the jobs (a file
  and its requirements) of a farm of a given size; pure.
- `rig.py`: `Farm`: PostgreSQL, Redis, a control plane and worker hosts as real
  processes, the simulators, uploads and bed clearing through the API.
- `processes.py`: a runhost in its own process group; CPU read from /proc.
- `checks.py`: what a run must show (every job once, on a matching printer, each
  simulator's record its jobs' files).
- `clients.py`: websocket clients that catch up by last id, and an API load.
- `crowd.py`: `Crowd`: those clients in processes of their own at nice 10, their
  results brought back to the harness.
"""
