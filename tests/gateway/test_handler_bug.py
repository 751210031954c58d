"""A bug inside a DoIP handler (here: a router whose submit() raises) costs one connection:
counted by the node's handler boundary (BusNode.handler_failed), its traceback logged once,
that socket closed; the entity keeps
serving UDP and new connections. The entity runs in a private network namespace (loopback),
stepped by the test on vecu's clock as the gateway's loop steps it."""

from __future__ import annotations

import json
import sys

import pytest

from vecu.live.netns import namespace_prefix, run_in_namespace

pytestmark = pytest.mark.skipif(namespace_prefix()[0] is None,
                                reason=namespace_prefix()[1] or "n/a")

CODE = r'''
import json, logging, socket, struct, subprocess, threading
from doipclient import DoIPClient
from vecu.bus import BusNode, open_bus
from vecu.clock import WallClock
from vecu.gateway.config import default_config
from vecu.gateway.entity import DoipEntity
from vecu.gateway.settings import settings_of

subprocess.run(["ip", "link", "set", "lo", "up"], check=True)
logged = []
logging.getLogger("vecu.gateway").addHandler(logging.Handler())
logging.getLogger("vecu.gateway").handlers[0].emit = lambda r: logged.append(
    (r.getMessage(), r.exc_info is not None))

class BrokenRouter:
    def submit(self, source, target, uds, reply):
        raise RuntimeError("a bug in the router")
    def cancel(self, source):
        pass

cfg = default_config()
node = BusNode(open_bus("virtual", "gateway-bug"), "gateway")
e = DoipEntity(cfg, settings_of(cfg), BrokenRouter(), node, 0.0, "127.0.0.1", 13400)
e.open()
clock = WallClock(spin_ns=0)
clock.start()
stop = threading.Event()
def loop():
    t = 0
    while not stop.is_set():
        t += 1_000_000
        clock.wait_until(t)
        e.step(t)
threading.Thread(target=loop, daemon=True).start()
res = {}
for k in range(2):  # two testers, each hits the bug
    c = DoIPClient("127.0.0.1", 0x10, client_logical_address=0x0E00 + k)
    try:
        c.send_diagnostic(bytearray(b"\x3e\x00"), timeout=1.0)
        res[f"tester{k}"] = "acked"
    except (OSError, TimeoutError) as exc:
        res[f"tester{k}"] = type(exc).__name__
    c.close()
res["identification_after"] = DoIPClient.get_entity("127.0.0.1")[1].vin
stop.set()
res["summary"] = e.summary()
res["logged"] = logged
e.close()
print(json.dumps(res))
'''


def test_a_handler_bug_closes_one_connection_and_the_entity_keeps_serving():
    res = run_in_namespace([sys.executable, "-c", CODE], timeout=60)
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout.strip().splitlines()[-1])
    assert out["tester0"] != "acked" and out["tester1"] != "acked"
    assert out["identification_after"] == "1VECU00SIM0000001"
    s = out["summary"]
    assert s["handler_errors"] == {"doip tcp: RuntimeError": 2} and s["closed"]["handler error"] == 2
    assert s["activations"] == {"0x10": 2}  # the second tester was served up to the bug
    tracebacks = [msg for msg, exc in out["logged"] if exc]
    assert len(tracebacks) == 1 and "handler_errors" in tracebacks[0]
