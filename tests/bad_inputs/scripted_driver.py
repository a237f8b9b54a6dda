"""A lab driver that misbehaves on request, for the bad-input corpus.

Arguments are faults, NAME=VALUE:
  hello=garbage|silent|exit      how to answer `hello`
  joints=[...]                   what `read_joints` returns (JSON)
  wrench=[...]                   what `read_wrench` returns (JSON)
  position=[...]                 what `measure` returns (JSON)
  sigma=[...]                    the 1-σ (mm) `measure` reports with it (JSON)
  measure=exit3|kill9|wrong_id|silent   how to fail at the first `measure`
Without faults it reads back the commanded joints, a zero wrench and a fixed
position.
"""
import json, os, signal, sys

faults = dict(arg.split("=", 1) for arg in sys.argv[1:])
q = [0.0] * 6
for line in sys.stdin:
    request = json.loads(line)
    method, rid = request["method"], request["id"]
    result = {}
    if method == "hello":
        fault = faults.get("hello")
        if fault == "garbage":
            print("\x00\xffnot json at all", flush=True)
            continue
        if fault == "silent":
            continue
        if fault == "exit":
            sys.exit(4)
        result = {"protocol": 1, "name": "scripted test driver"}
    elif method == "move_joints":
        q = request["params"]["q_deg"]
    elif method == "read_joints":
        result = {"q_deg": json.loads(faults["joints"]) if "joints" in faults else q}
    elif method == "read_wrench":
        result = {"wrench": json.loads(faults.get("wrench", "[0, 0, 0, 0, 0, 0]"))}
    elif method == "measure":
        fault = faults.get("measure")
        if fault == "exit3":
            sys.exit(3)
        if fault == "kill9":
            os.kill(os.getpid(), signal.SIGKILL)
        if fault == "silent":
            continue
        if fault == "wrong_id":
            rid += 7
        result = {"position_mm": json.loads(faults.get("position", "[1000.0, 0.0, 1000.0]"))}
        if "sigma" in faults:
            result["sigma_mm"] = json.loads(faults["sigma"])
    elif method == "shutdown":
        print(json.dumps({"id": rid, "result": {}}), flush=True)
        break
    print(json.dumps({"id": rid, "result": result}), flush=True)
