"""The fake Spot's gRPC side: the services its directory lists, the gate every RPC passes
(:class:`Gate`: call log, scripted faults, user-token check, late replies under the 'slow' fault
or ``delay_calls``) and :class:`SpotServicer`, one handler per Spot RPC the SDK backend uses
(auth, directory, robot id, time sync, robot state, lease, e-stop, power, robot command, images,
manipulation).

Apart from the robot (``server.py``, the state machine the handlers read and change) because it is
the Spot API surface, read RPC by RPC against the SDK's services. ``FakeSpot.start`` serves it;
``fake`` is that :class:`~robots.spot.fake_spot.server.FakeSpot`, named in annotations only:
``server.py`` imports this module, so this module cannot import it.
"""

from __future__ import annotations

import secrets
import time

import grpc
import numpy as np
from bosdyn.api import (
    auth_pb2,
    auth_service_pb2_grpc,
    directory_pb2,
    directory_service_pb2_grpc,
    estop_pb2,
    estop_service_pb2_grpc,
    header_pb2,
    image_pb2,
    image_service_pb2_grpc,
    lease_pb2,
    lease_service_pb2_grpc,
    manipulation_api_pb2,
    manipulation_api_service_pb2_grpc,
    power_pb2,
    power_service_pb2_grpc,
    robot_command_pb2,
    robot_command_service_pb2_grpc,
    robot_id_pb2,
    robot_id_service_pb2_grpc,
    robot_state_pb2,
    robot_state_service_pb2_grpc,
    time_sync_pb2,
    time_sync_service_pb2_grpc,
)

from robots.spot import sdk_conversions as cv
from robots.spot.fake_spot.bookkeeping import STOP_LEVEL_NAMES, Endpoint
from robots.spot.fake_spot.protocol import (
    Reject,
    feedback,
    fill_status,
    image_response,
    kinematic_tree,
    parse_command,
    robot_state,
    untimed,
)
from robots.spot.fake_spot.time_sync import InvalidTimeSyncRequest

# Services the directory lists: name -> (type, authority). The authorities must be covered by the
# server certificate's subjectAltNames ("*.spot.robot" covers the non-bootstrap ones).
SERVICES: dict[str, tuple[str, str]] = {
    "auth": ("bosdyn.api.AuthService", "auth.spot.robot"),
    "directory": ("bosdyn.api.DirectoryService", "api.spot.robot"),
    "robot-id": ("bosdyn.api.RobotIdService", "id.spot.robot"),
    "time-sync": ("bosdyn.api.TimeSyncService", "api.spot.robot"),
    "robot-state": ("bosdyn.api.RobotStateService", "api.spot.robot"),
    "lease": ("bosdyn.api.LeaseService", "api.spot.robot"),
    "estop": ("bosdyn.api.EstopService", "api.spot.robot"),
    "power": ("bosdyn.api.PowerService", "api.spot.robot"),
    "robot-command": ("bosdyn.api.RobotCommandService", "command.spot.robot"),
    "image": ("bosdyn.api.ImageService", "api.spot.robot"),
    "manipulation": ("bosdyn.api.ManipulationApiService", "manipulation.spot.robot"),
}
_UNAUTHENTICATED_SERVICES = ("bosdyn.api.AuthService", "bosdyn.api.RobotIdService")


class SimulatorBusy(Exception):
    """An RPC handler could not get the simulator (stopped, or held by a hung command)."""


class Gate(grpc.ServerInterceptor):
    """Every RPC: record it, apply scripted faults, require a valid user token (except for the
    auth and robot-id services, as on the robot), and hold the reply back under the 'slow' fault
    or a ``delay_calls`` rule. A call the link loses (``lease_retains_lost``) never reaches the
    robot: not recorded, not acted on, unanswered until the caller's deadline."""

    def __init__(self, fake: FakeSpot):
        self._fake = fake

    def intercept_service(self, continuation, handler_call_details):
        handler = continuation(handler_call_details)
        if handler is None or handler.unary_unary is None:
            return handler
        fake = self._fake
        method = handler_call_details.method
        metadata = {k: v for k, v in (handler_call_details.invocation_metadata or ())}
        inner = handler.unary_unary
        service = method.strip("/").split("/")[0]

        def gated(request, context):
            name = method.rsplit("/", 1)[-1]
            if fake.lost_on_the_way(name):
                fake.hold_lost_call(context)
                context.abort(grpc.StatusCode.DEADLINE_EXCEEDED, f"{name} lost on the way (fault injection)")
            delay = fake.on_call(name, context)
            if service not in _UNAUTHENTICATED_SERVICES and not fake.check_token(metadata):
                context.abort(grpc.StatusCode.UNAUTHENTICATED, "missing or invalid user token")
            try:
                response = inner(request, context)
            except SimulatorBusy as exc:
                context.abort(grpc.StatusCode.UNAVAILABLE, str(exc))
            fake.slow_delay(context, delay)
            return response

        return grpc.unary_unary_rpc_method_handler(gated, request_deserializer=handler.request_deserializer,
                                                   response_serializer=handler.response_serializer)


class SpotServicer(auth_service_pb2_grpc.AuthServiceServicer,
                    directory_service_pb2_grpc.DirectoryServiceServicer,
                    robot_id_service_pb2_grpc.RobotIdServiceServicer,
                    time_sync_service_pb2_grpc.TimeSyncServiceServicer,
                    robot_state_service_pb2_grpc.RobotStateServiceServicer,
                    lease_service_pb2_grpc.LeaseServiceServicer,
                    estop_service_pb2_grpc.EstopServiceServicer,
                    power_service_pb2_grpc.PowerServiceServicer,
                    robot_command_service_pb2_grpc.RobotCommandServiceServicer,
                    image_service_pb2_grpc.ImageServiceServicer,
                    manipulation_api_service_pb2_grpc.ManipulationApiServiceServicer):
    """All the Spot services of the fake in one object (method names do not collide)."""

    def __init__(self, fake: FakeSpot):
        self.f = fake

    # ---------------------------------------------------------------- auth, directory, id, time
    def GetAuthToken(self, request, context):
        resp = auth_pb2.GetAuthTokenResponse()
        f = self.f
        if request.token:
            ok = f.check_token({"authorization": "Bearer " + request.token})
            resp.status = resp.STATUS_OK if ok else resp.STATUS_INVALID_TOKEN
        else:
            ok = f.credentials_ok(request.username, request.password)
            resp.status = resp.STATUS_OK if ok else resp.STATUS_INVALID_LOGIN
        if ok:
            resp.token = f.issue_token()
        return f.header(resp, request)

    def ListServiceEntries(self, request, context):
        resp = directory_pb2.ListServiceEntriesResponse()
        for name, (type_, authority) in SERVICES.items():
            resp.service_entries.add(name=name, type=type_, authority=authority, user_token_required=True)
        return self.f.header(resp, request)

    def GetServiceEntry(self, request, context):
        resp = directory_pb2.GetServiceEntryResponse()
        if request.service_name in SERVICES:
            type_, authority = SERVICES[request.service_name]
            resp.status = resp.STATUS_OK
            resp.service_entry.CopyFrom(directory_pb2.ServiceEntry(name=request.service_name, type=type_,
                                                                   authority=authority))
        else:
            resp.status = resp.STATUS_NONEXISTENT_SERVICE
        return self.f.header(resp, request)

    def GetRobotId(self, request, context):
        resp = robot_id_pb2.RobotIdResponse()
        rid = resp.robot_id
        rid.serial_number, rid.species, rid.version = "FAKE-SPOT-0001", "spot", "V3"
        rid.nickname, rid.computer_serial_number = self.f.robot_name, "FAKE-CORE-0001"
        rid.software_release.version.major_version = 5
        rid.software_release.version.minor_version = 2
        return self.f.header(resp, request)

    def TimeSyncUpdate(self, request, context):
        """Estimated from the round trips the client reports (``time_sync.TimeSyncService``)."""
        f = self.f
        received = f.robot_now()
        if f.has_fault("time_sync_loss"):
            return f.header(time_sync_pb2.TimeSyncUpdateResponse(), request,
                            header_pb2.CommonError.CODE_INTERNAL_SERVER_ERROR, "time-sync service failed",
                            received=received)
        try:
            resp = f.time_sync.update(request)
        except InvalidTimeSyncRequest as exc:
            return f.header(time_sync_pb2.TimeSyncUpdateResponse(), request,
                            header_pb2.CommonError.CODE_INVALID_REQUEST, str(exc), received=received)
        return f.header(resp, request, received=received)

    # ---------------------------------------------------------------- robot state
    def GetRobotState(self, request, context):
        f = self.f
        f.stop_level()   # applies e-stop endpoint timeouts lazily
        resp = robot_state_pb2.RobotStateResponse()
        # A paced robot releases the simulator between control steps: the state is always fresh.
        if f.sim_lock.acquire(timeout=0.5 if f.time_scale is None else 5.0):
            try:
                state = robot_state(f)
                f._state_cache = state
            finally:
                f.sim_lock.release()
        else:  # unpaced, busy in the simulator: the last kinematic state, power and e-stop as they are now
            state = robot_state_pb2.RobotState()
            if f._state_cache is not None:
                state.CopyFrom(f._state_cache)
            fill_status(f, state)
        resp.robot_state.CopyFrom(state)
        return f.header(resp, request)

    # ---------------------------------------------------------------- lease
    def _lease_owner_proto(self):
        return lease_pb2.LeaseOwner(client_name=self.f.lease_owner or "")

    def _grant_lease(self, resp, request) -> None:
        """Give the body lease to the caller (a new sequence number); call with ``f._lock`` held."""
        f = self.f
        f._lease_seq += 1
        f.lease_owner = request.header.client_name or "unnamed client"
        f.lease_granted()
        resp.status = resp.STATUS_OK
        resp.lease.CopyFrom(f.current_lease())
        resp.lease_owner.CopyFrom(self._lease_owner_proto())

    def AcquireLease(self, request, context):
        f = self.f
        resp = lease_pb2.AcquireLeaseResponse()
        with f._lock:
            if request.resource != "body":
                resp.status = resp.STATUS_INVALID_RESOURCE
            elif f.lease_owner is not None and not f.lease_stale:    # a stale one may be acquired
                resp.status = resp.STATUS_RESOURCE_ALREADY_CLAIMED
                resp.lease_owner.CopyFrom(self._lease_owner_proto())
            else:
                self._grant_lease(resp, request)
        return f.header(resp, request)

    def TakeLease(self, request, context):
        f = self.f
        resp = lease_pb2.TakeLeaseResponse()
        with f._lock:
            if request.resource != "body":
                resp.status = resp.STATUS_INVALID_RESOURCE
            else:
                self._grant_lease(resp, request)
        return f.header(resp, request)

    def ReturnLease(self, request, context):
        f = self.f
        resp = lease_pb2.ReturnLeaseResponse()
        result = f.check_lease(request.lease)
        with f._lock:
            if result.status == lease_pb2.LeaseUseResult.STATUS_OK:
                f.lease_owner = None
                f.lease_returned()
                resp.status = resp.STATUS_OK
            else:
                resp.status = resp.STATUS_NOT_ACTIVE_LEASE
        return f.header(resp, request)

    def RetainLease(self, request, context):
        """The owner's keep-alive: an OK retain is what keeps the robot's comms-loss behaviour
        away and makes a stale lease fresh (comms_loss.py)."""
        resp = lease_pb2.RetainLeaseResponse()
        resp.lease_use_result.CopyFrom(self.f.check_lease(request.lease))
        if resp.lease_use_result.status == lease_pb2.LeaseUseResult.STATUS_OK:
            self.f.lease_retained()
        return self.f.header(resp, request)

    def ListLeases(self, request, context):
        f = self.f
        resp = lease_pb2.ListLeasesResponse()
        with f._lock:
            res = resp.resources.add(resource="body")
            if f.lease_owner:
                res.lease.CopyFrom(f.current_lease())
                res.lease_owner.CopyFrom(self._lease_owner_proto())
                res.is_stale = f.lease_stale
        return f.header(resp, request)

    # ---------------------------------------------------------------- e-stop
    def _config(self) -> estop_pb2.EstopConfig:
        f = self.f
        cfg = estop_pb2.EstopConfig(unique_id=f._estop_config_id)
        for ep in f._endpoints.values():
            cfg.endpoints.add().CopyFrom(ep.proto)
        return cfg

    def GetEstopConfig(self, request, context):
        resp = estop_pb2.GetEstopConfigResponse()
        with self.f._lock:
            resp.active_config.CopyFrom(self._config())
        return self.f.header(resp, request)

    def SetEstopConfig(self, request, context):
        f = self.f
        resp = estop_pb2.SetEstopConfigResponse()
        with f._lock:
            if f.powered:
                resp.status = resp.STATUS_MOTORS_ON
            elif request.target_config_id != f._estop_config_id:
                resp.status = resp.STATUS_INVALID_ID
            else:
                f._estop_config_id = "estop-config-" + secrets.token_hex(3)
                f._endpoints = {}
                for ep in request.config.endpoints:
                    proto = estop_pb2.EstopEndpoint()
                    proto.CopyFrom(ep)
                    proto.unique_id = "endpoint-" + secrets.token_hex(3)
                    f._endpoints[proto.unique_id] = Endpoint(proto)
                resp.status = resp.STATUS_SUCCESS
            resp.active_config.CopyFrom(self._config())
        return f.header(resp, request)

    def RegisterEstopEndpoint(self, request, context):
        f = self.f
        resp = estop_pb2.RegisterEstopEndpointResponse()
        with f._lock:
            # The target names a slot of the active configuration, by unique id or by role.
            target = request.target_endpoint
            slot = next((uid for uid, ep in f._endpoints.items()
                         if (target.unique_id and uid == target.unique_id)
                         or (not target.unique_id and target.role and ep.proto.role == target.role)), None)
            if request.target_config_id != f._estop_config_id:
                resp.status = resp.STATUS_CONFIG_MISMATCH
            elif slot is None:
                resp.status = resp.STATUS_ENDPOINT_MISMATCH
            else:
                old = f._endpoints.pop(slot)
                proto = estop_pb2.EstopEndpoint()
                proto.CopyFrom(request.new_endpoint)
                proto.unique_id = "endpoint-" + secrets.token_hex(3)
                proto.role = proto.role or old.proto.role
                f._endpoints[proto.unique_id] = Endpoint(proto)
                resp.new_endpoint.CopyFrom(proto)
                resp.status = resp.STATUS_SUCCESS
        return f.header(resp, request)

    def DeregisterEstopEndpoint(self, request, context):
        f = self.f
        resp = estop_pb2.DeregisterEstopEndpointResponse()
        with f._lock:
            if f.powered or f.powering_on():        # "cannot deregister an endpoint while the motors are on"
                resp.status = resp.STATUS_MOTORS_ON
            elif request.target_endpoint.unique_id in f._endpoints:
                del f._endpoints[request.target_endpoint.unique_id]
                resp.status = resp.STATUS_SUCCESS
            else:
                resp.status = resp.STATUS_ENDPOINT_MISMATCH
        return f.header(resp, request)

    def EstopCheckIn(self, request, context):
        """A check-in must answer the endpoint's previous challenge (``Endpoint.answers``). A
        wrong answer is STATUS_INCORRECT_CHALLENGE_RESPONSE with a new challenge (the SDK takes
        the challenge from that error response, ``EstopEndpoint``); it does not count as a
        valid response, so the endpoint's ``timeout`` runs on, and it cannot release a stop.
        A stop it asks for (CUT, SETTLE_THEN_CUT) is applied anyway: what a robot does with
        the level of a refused check-in is not documented, and the fake keeps to the safe side."""
        f = self.f
        resp = estop_pb2.EstopCheckInResponse()
        with f._lock:
            ep = f._endpoints.get(request.endpoint.unique_id)
            if ep is None:
                resp.status = resp.STATUS_ENDPOINT_UNKNOWN
            else:
                if ep.answers(request.challenge, request.response):
                    ep.level = request.stop_level
                    ep.last_checkin = time.monotonic()
                    resp.status = resp.STATUS_OK
                else:
                    if request.stop_level in (estop_pb2.ESTOP_LEVEL_CUT, estop_pb2.ESTOP_LEVEL_SETTLE_THEN_CUT):
                        ep.level = min(ep.level, request.stop_level)
                    resp.status = resp.STATUS_INCORRECT_CHALLENGE_RESPONSE
                ep.challenge = secrets.randbits(64)      # uint64 in estop.proto
                resp.challenge = ep.challenge
        f.stop_level()   # a CUT check-in cuts power
        return f.header(resp, request)

    def GetEstopSystemStatus(self, request, context):
        f = self.f
        resp = estop_pb2.GetEstopSystemStatusResponse()
        level, who = f.stop_level()
        with f._lock:
            now = time.monotonic()
            for ep in f._endpoints.values():
                e = resp.status.endpoints.add()
                e.endpoint.CopyFrom(ep.proto)
                e.stop_level = ep.level
                e.time_since_valid_response.CopyFrom(cv.seconds_to_duration(now - ep.last_checkin))
        resp.status.stop_level = level
        resp.status.stop_level_details = who
        return f.header(resp, request)

    # ---------------------------------------------------------------- power
    def _lease_refused(self, resp, request) -> bool:
        """The robot's verdict on the lease a command carries, put in ``resp``; True when it is
        refused (the response then goes back as it is, as a real robot's does)."""
        resp.lease_use_result.CopyFrom(self.f.check_lease(request.lease, newest=True))
        if resp.lease_use_result.status != lease_pb2.LeaseUseResult.STATUS_OK:
            return True
        self.f.lease_used()
        return False

    def PowerCommand(self, request, context):
        f = self.f
        resp = power_pb2.PowerCommandResponse()
        if self._lease_refused(resp, request):
            resp.status = power_pb2.STATUS_UNKNOWN
            return f.header(resp, request)
        level, _ = f.stop_level()
        with f._lock:
            resp.power_command_id = f._next_id
            f._next_id += 1
            if f.powering_on():            # one power command at a time, not interruptible (power_service.proto)
                resp.status = power_pb2.STATUS_COMMAND_IN_PROGRESS
            elif request.request == power_pb2.PowerCommandRequest.REQUEST_ON_MOTORS:
                if level != estop_pb2.ESTOP_LEVEL_NONE:
                    resp.status = power_pb2.STATUS_ESTOPPED
                elif f.critical_system_faults():    # "Cannot power on due to a fault" (FaultedError)
                    resp.status = power_pb2.STATUS_FAULTED
                elif f.power_on_seconds > 0 and not f.powered:
                    f._powering_on_until = time.monotonic() + f.power_on_seconds
                    resp.status = power_pb2.STATUS_IN_PROGRESS
                else:
                    f.powered = True
                    resp.status = power_pb2.STATUS_SUCCESS
            elif request.request == power_pb2.PowerCommandRequest.REQUEST_OFF_MOTORS:
                f._cut_power("power off requested")
                resp.status = power_pb2.STATUS_SUCCESS
            else:
                resp.status = power_pb2.STATUS_INTERNAL_ERROR
        return f.header(resp, request)

    def PowerCommandFeedback(self, request, context):
        f = self.f
        with f._lock:
            busy = f.powering_on()
        resp = power_pb2.PowerCommandFeedbackResponse(status=power_pb2.STATUS_IN_PROGRESS if busy
                                                      else power_pb2.STATUS_SUCCESS)
        return f.header(resp, request)

    # ---------------------------------------------------------------- robot command
    def RobotCommand(self, request, context):
        f = self.f
        R = robot_command_pb2.RobotCommandResponse
        resp = R()
        if self._lease_refused(resp, request):
            return f.header(resp, request)
        try:
            with f._lock:
                clock_ok = f.time_sync.established(request.clock_identifier) and not f.has_fault("time_sync_loss")
            if not clock_ok and not untimed(request.command):
                raise Reject(R.STATUS_NO_TIMESYNC, "unknown clock identifier: time sync with the robot first")
            kind, extra = parse_command(f, request.command, request)
            level, who = f.stop_level()
            if kind not in ("stop", "safe_power_off") and not f.powered:
                raise Reject(R.STATUS_NOT_POWERED_ON, "motor power is off" +
                              (f" (e-stop {STOP_LEVEL_NAMES.get(level)} from {who})"
                               if level != estop_pb2.ESTOP_LEVEL_NONE else ""))
            with f._lock:
                faulted = f.behavior_fault is not None
            if kind not in ("stop", "safe_power_off") and faulted:
                raise Reject(R.STATUS_BEHAVIOR_FAULT, "the robot has a behavior fault; clear it first")
        except Reject as rej:
            resp.status, resp.message = rej.status, str(rej)
            return f.header(resp, request)
        cmd = f.add_command(kind, request.command, **extra)
        resp.status, resp.robot_command_id = R.STATUS_OK, cmd.id
        return f.header(resp, request)

    def RobotCommandFeedback(self, request, context):
        f = self.f
        resp = robot_command_pb2.RobotCommandFeedbackResponse()
        f.stop_level()
        with f._lock:
            cmd = f.commands.get(request.robot_command_id)
            if cmd is None or cmd.kind == "pick":
                return f.header(resp, request, header_pb2.CommonError.CODE_INVALID_REQUEST,
                                f"unknown robot command id {request.robot_command_id}")
            resp.feedback.CopyFrom(feedback(cmd))
        return f.header(resp, request)

    def ClearBehaviorFault(self, request, context):
        f = self.f
        C = robot_command_pb2.ClearBehaviorFaultResponse
        resp = C()
        if self._lease_refused(resp, request):
            return f.header(resp, request)
        with f._lock:
            fault = f.behavior_fault
            if fault is not None and fault.behavior_fault_id == request.behavior_fault_id and \
                    fault.status == fault.STATUS_CLEARABLE:
                f.behavior_fault, resp.status = None, C.STATUS_CLEARED
            else:                       # no such fault, another id, or not clearable
                resp.status = C.STATUS_NOT_CLEARED
        return f.header(resp, request)

    # ---------------------------------------------------------------- images
    def ListImageSources(self, request, context):
        f = self.f
        resp = image_pb2.ListImageSourcesResponse()
        intr = f.sim.intrinsics
        for name, kind in ((cv.HAND_COLOR_SOURCE, image_pb2.ImageSource.IMAGE_TYPE_VISUAL),
                           (cv.HAND_DEPTH_SOURCE, image_pb2.ImageSource.IMAGE_TYPE_DEPTH)):
            src = resp.image_sources.add(name=name, rows=intr.height, cols=intr.width, image_type=kind)
            src.pinhole.CopyFrom(cv.intrinsics_to_pinhole(intr))
            if kind == image_pb2.ImageSource.IMAGE_TYPE_DEPTH:
                src.depth_scale = f.depth_scale
        return f.header(resp, request)

    def GetImage(self, request, context):
        f = self.f
        resp = image_pb2.GetImageResponse()
        names = [r.image_source_name for r in request.image_requests]
        known = (cv.HAND_COLOR_SOURCE, cv.HAND_DEPTH_SOURCE)
        obs = snapshot = None
        if any(n in known for n in names):
            with f.sim_for_rpc("rendering the hand camera"):
                obs = f.sim.observe()
                f.remember_frame(obs)
                snapshot = cv.frame_tree(kinematic_tree(f.sim))
            acquired = f.robot_now()
        for r in request.image_requests:
            if r.image_source_name not in known:
                resp.image_responses.add(status=image_pb2.ImageResponse.STATUS_UNKNOWN_CAMERA).source.name = \
                    r.image_source_name
                continue
            resp.image_responses.add().CopyFrom(image_response(f, r, obs, snapshot, acquired))
        return f.header(resp, request)

    # ---------------------------------------------------------------- manipulation
    def ManipulationApi(self, request, context):
        f = self.f
        resp = manipulation_api_pb2.ManipulationApiResponse()
        if self._lease_refused(resp, request):
            return f.header(resp, request)
        if request.WhichOneof("manipulation_cmd") != "pick_object_in_image":
            return f.header(resp, request, header_pb2.CommonError.CODE_INVALID_REQUEST,
                            "the fake implements pick_object_in_image only")
        pick = request.pick_object_in_image
        try:
            T_world_cam = cv.tform(pick.transforms_snapshot_for_camera, cv.ODOM, pick.frame_name_image_sensor)
        except (KeyError, ValueError) as exc:
            return f.header(resp, request, header_pb2.CommonError.CODE_INVALID_REQUEST,
                            f"bad camera snapshot: {exc}")
        pixel = (int(round(pick.pixel_xy.x)), int(round(pick.pixel_xy.y)))
        if not f.powered or f.behavior_fault is not None:
            cmd = f.add_command("pick", request, T_world_cam=T_world_cam, pixel=pixel)
            with f._lock:
                cmd.state, cmd.success = "frozen", False
                cmd.extra["manip_state"] = manipulation_api_pb2.MANIP_STATE_GRASP_FAILED
        else:
            cmd = f.add_command("pick", request, T_world_cam=T_world_cam, pixel=pixel)
        resp.manipulation_cmd_id = cmd.id
        return f.header(resp, request)

    def ManipulationApiFeedback(self, request, context):
        f = self.f
        resp = manipulation_api_pb2.ManipulationApiFeedbackResponse()
        with f._lock:
            cmd = f.commands.get(request.manipulation_cmd_id)
            if cmd is None or cmd.kind != "pick":
                return f.header(resp, request, header_pb2.CommonError.CODE_INVALID_REQUEST,
                                f"unknown manipulation command id {request.manipulation_cmd_id}")
            resp.manipulation_cmd_id = cmd.id
            if cmd.state in ("queued", "hung"):
                resp.current_state = cmd.extra.get("hung_manip_state", manipulation_api_pb2.MANIP_STATE_SEARCHING_FOR_GRASP)
            elif cmd.state == "running":
                resp.current_state = manipulation_api_pb2.MANIP_STATE_MOVING_TO_GRASP
            elif cmd.state in ("overridden", "frozen") and "manip_state" not in cmd.extra:
                resp.current_state = manipulation_api_pb2.MANIP_STATE_GRASP_FAILED
            else:
                resp.current_state = cmd.extra.get("manip_state", manipulation_api_pb2.MANIP_STATE_GRASP_FAILED)
            last = cmd.extra.get("reported_manip_state")
            if cmd.state == "frozen" and last is not None and f.has_fault("manip_feedback_stale"):
                # ended by the robot itself, still reporting its last state (or the one scripted)
                said = f.faults["manip_feedback_stale"].get("state")
                resp.current_state = manipulation_api_pb2.ManipulationFeedbackState.Value(said) if said else last
            cmd.extra["reported_manip_state"] = resp.current_state
            T_grasp = cmd.extra.get("grasp_hand_pose")
        if T_grasp is not None:
            resp.transforms_snapshot_manipulation_data.CopyFrom(cv.frame_tree({
                cv.ODOM: ("", np.eye(4)), cv.VISION: (cv.ODOM, np.eye(4)),
                cv.GRASP_SOLUTION_FRAME: (cv.ODOM, T_grasp)}))
        return f.header(resp, request)
