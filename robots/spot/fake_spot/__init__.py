"""A fake Spot robot for tests and hardware dry runs: the Spot gRPC services over TLS on
127.0.0.1, backed by the PyBullet simulation, with fault injection.

``launch.start_demo_fake`` builds the demo scene and starts one; ``server.FakeSpot`` is the
server; ``certs.make_test_pki`` makes the throwaway CA it presents. Importing this package is
cheap; the submodules pull in grpc, bosdyn and PyBullet.
"""
