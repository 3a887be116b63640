"""An independent MAVLink client (MAVSDK, the Dronecode SDK) drives an autopilot through
connect → arm → offboard → hold; prints what it saw as one JSON line. Run as a script (its own
process: MAVSDK's native library owns threads that outlive a failed call).

Usage: python tests/mavsdk_client.py udpin://0.0.0.0:PORT
"""

from __future__ import annotations

import asyncio
import json
import sys
import time

import mavsdk.logging as mavsdk_logging
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.offboard import OffboardAsync, PositionNedYaw
from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync


async def _until(getter, ok, timeout_s: float, what: str):
    t_end = time.monotonic() + timeout_s
    while True:
        value = await getter()
        if ok(value):
            return value
        if time.monotonic() > t_end:
            raise RuntimeError(f"no {what} within {timeout_s} s (last: {value})")
        await asyncio.sleep(0.05)


async def fly(url: str) -> dict:
    seen: dict = {}
    config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    async with Mavsdk(config) as sdk:
        await sdk.add_any_connection(url)
        drone = await sdk.first_autopilot(timeout_s=10.0)
        if drone is None:
            raise RuntimeError("MAVSDK found no autopilot")
        seen["autopilot"] = (await drone.autopilot_type()).name
        action, offboard = ActionAsync(drone), OffboardAsync(drone)
        telemetry = TelemetryAsync(drone)
        seen["mode_at_connect"] = (await telemetry.flight_mode()).name
        await action.arm()
        await _until(telemetry.armed, bool, 3.0, "armed")
        await offboard.set_position_ned(PositionNedYaw(0.0, 0.0, -3.0, 0.0))
        await offboard.start()
        await _until(telemetry.flight_mode, lambda m: m == FlightMode.OFFBOARD, 3.0, "OFFBOARD")
        pv = await _until(telemetry.position_velocity_ned, lambda p: p.position.down_m < -2.0,
                          15.0, "climb to 3 m in offboard")
        seen["offboard_height_m"] = -pv.position.down_m
        await action.hold()
        mode = await _until(telemetry.flight_mode, lambda m: m == FlightMode.HOLD, 3.0, "HOLD")
        seen["mode_after_hold"] = mode.name
        await asyncio.sleep(2.0)  # holding: it stays where it was
        pv = await telemetry.position_velocity_ned()
        seen["hold_height_m"] = -pv.position.down_m
        seen["armed_in_hold"] = await telemetry.armed()
        for plugin in (offboard, action, telemetry):
            plugin.destroy()
    return seen


def main() -> int:
    mavsdk_logging.log_subscribe(lambda *_: True)  # silence the library's own log lines
    try:
        seen = asyncio.run(asyncio.wait_for(fly(sys.argv[1]), 60.0))
    except Exception as exc:  # report any failure as data for the test to show
        print(json.dumps({"error": f"{type(exc).__name__}: {exc}"}), flush=True)
        return 1
    print(json.dumps(seen), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
