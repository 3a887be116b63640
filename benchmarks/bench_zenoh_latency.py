"""Prediction latency over Zenoh on loopback: ``python benchmarks/bench_zenoh_latency.py [N]``.

Two ZenohTransports in one process (peer to peer, 127.0.0.1); N prediction-sized messages at
100 Hz, each carrying its send time; the receiver polls ``receive`` every 0.2 ms, so the figure
includes up to 0.2 ms of polling. Prints one JSON object last.
"""

import json
import struct
import sys
import time

import numpy as np

from uavmpc.comms.zenoh_link import ZenohTransport
from uavmpc.drivers.swarm import free_ports


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 1000
    a_port, b_port = free_ports(2)
    with ZenohTransport("a", swarm="lat", listen=[f"tcp/127.0.0.1:{a_port}"]) as a, \
            ZenohTransport("b", swarm="lat", listen=[f"tcp/127.0.0.1:{b_port}"],
                           connect=[f"tcp/127.0.0.1:{a_port}"]) as b:
        pad = bytes(1301 - 12)
        deadline = time.time() + 5.0
        while time.time() < deadline and not b.receive("b", 0.0):  # discovery
            a.publish(struct.pack("<qI", time.time_ns(), 0) + pad, "a", 0.0)
            time.sleep(0.05)
        latencies = []
        for i in range(n):
            a.publish(struct.pack("<qI", time.time_ns(), i + 1) + pad, "a", 0.0)
            t_next = time.perf_counter() + 0.01
            while time.perf_counter() < t_next:
                for data in b.receive("b", 0.0):
                    sent_ns, seq = struct.unpack_from("<qI", data)
                    if seq:
                        latencies.append((time.time_ns() - sent_ns) / 1e6)
                time.sleep(0.0002)
    ms = np.array(latencies)
    result = {"messages": n, "received": len(ms), "bytes": 1301,
              "latency_median_ms": round(float(np.median(ms)), 3),
              "latency_p99_ms": round(float(np.percentile(ms, 99)), 3),
              "latency_max_ms": round(float(ms.max()), 3)}
    print(json.dumps(result))


if __name__ == "__main__":
    main()
