"""A node's tick under a message flood: ``python benchmarks/bench_node_flood.py [SECONDS]``.

One simulated node hovering (a thread of this process, Zenoh on 127.0.0.1), flown twice for
SECONDS (default 8): first alone (the reference), then while a second Zenoh peer sends it 1000
valid predictions per second from far away. For each run: the tick period's median, p99 and
maximum, the overruns (ticks that started late), and how many of the flood's messages the node
accepted. A node that keeps its 10 ms tick under the flood has the same figures in both runs.
Prints one JSON object last.
"""

import json
import sys
import threading
import time

import numpy as np

from uavmpc.comms.message import SCHEMA_VERSION, PredictionMessage, encode
from uavmpc.comms.zenoh_link import ZenohTransport
from uavmpc.drivers.node import Node, warm_up
from uavmpc.drivers.swarm import free_ports
from uavmpc.plant import Airframe

HORIZON_S = np.cumsum(np.r_[0.01, np.full(39, 0.2)])


def fly(seconds: float, flood_hz: float) -> dict:
    ports = free_ports(2)
    eps = [f"tcp/127.0.0.1:{p}" for p in ports]
    swarm = f"flood{ports[0]}"
    with ZenohTransport("uav1", swarm=swarm, listen=[eps[0]]) as node_tx, \
            ZenohTransport("flooder", swarm=swarm, listen=[eps[1]], connect=[eps[0]]) as other:
        node = Node("uav1", 5, Airframe.packaged("f550"), node_tx, start_m=(0.0, 0.0, 5.0))
        states = other.subscribe("uav1/state", maxlen=1000)
        thread = threading.Thread(target=node.run, args=(seconds,), daemon=True)
        thread.start()
        deadline = time.time() + 30.0
        while not states.drain() and time.time() < deadline:  # discovery
            time.sleep(0.05)
        far = np.tile([500.0, 500.0, 5.0], (40, 1))
        sent = 0
        while thread.is_alive() and flood_hz > 0:
            now = time.time()
            msg = PredictionMessage(SCHEMA_VERSION, "flooder", 1, now, now + HORIZON_S, far, True)
            for _ in range(10):
                other.publish(encode(msg), "flooder", 0.0)
                sent += 1
            time.sleep(10.0 / flood_hz)
        thread.join()
    s = node.stats
    return {"flood_hz": flood_hz, "sent": sent, "accepted": s.accepted, "ticks": s.ticks,
            "overruns": s.overruns, "period_p50_ms": round(s.period_p50_ms, 3),
            "period_p99_ms": round(s.period_p99_ms, 3),
            "period_max_ms": round(s.period_max_ms, 3)}


def main() -> None:
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 8.0
    warm_up(Airframe.packaged("f550"))
    reference = fly(seconds, 0.0)
    print("alone:", json.dumps(reference), flush=True)
    flooded = fly(seconds, 1000.0)
    print("flooded:", json.dumps(flooded), flush=True)
    ratios = {f"{q}_ratio": round(flooded[f"period_{q}_ms"] / reference[f"period_{q}_ms"], 3)
              for q in ("p50", "p99")}
    print(json.dumps({"seconds": seconds, "alone": reference, "flooded": flooded, **ratios}))


if __name__ == "__main__":
    main()
