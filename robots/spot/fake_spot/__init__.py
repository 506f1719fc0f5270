"""A fake Spot robot for tests and hardware dry runs: the Spot gRPC services over TLS on
127.0.0.1, backed by the PyBullet simulation, with fault injection.

``launch.start_demo_fake`` builds the demo scene and starts one; ``server.FakeSpot`` is the
server (the robot: faults, leases, e-stop, power, commands, the robot thread); ``servicer`` holds
its gRPC gate and RPC handlers, ``protocol`` builds the Spot messages they answer with and parses
the commands they accept, ``sim_execution`` carries out accepted commands on the simulator, and
``bookkeeping`` holds the records they share (e-stop endpoints, commands); ``sim_robot`` and
``sim_view`` are the simulator's side; ``certs.make_test_pki`` makes the throwaway CA it presents.
Importing this package is cheap; the submodules pull in grpc, bosdyn and PyBullet.
"""
