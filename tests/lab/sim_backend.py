#!/usr/bin/env python3
"""egcal's simulator as the physics behind the lab emulators (Python 3.11, standard library only).

SimBackend(command) starts a driver that speaks schemas/driver-protocol.md (e.g.
["/path/egcal", "sim-driver", "--robot", R, "--truth", T, "--seed", "7"]) with its stdin and
stdout as pipes (its stderr passes through to ours), says `hello` with protocol 1, and then
forwards the device emulators' calls to it, one at a time under one lock:

  move_joints(cw_id, q)  apply_wrench(w)  release_wrench()  read_wrench() -> [6]
  read_joints() -> [6]   measure() -> {"position_mm": [3], "measured_at_us"?: int, "sigma_mm"?: [3]}
  shutdown()

An error reply raises BackendError(message), with the reply's `code` and `transient` as attributes.
A driver that exits, closes its stdout, breaks the protocol or does not answer within `timeout_s`
also raises BackendError, and every later call raises it again.

egcal's in-process simulator draws its noise from a stream re-seeded by each move_joints, so
the emulators call the backend in the campaign's order (move_joints, apply_wrench, read_wrench,
read_joints, measure, release_wrench) to see the same readings as `egcal run` with the simulator.
"""
import json
import math
import queue
import subprocess
import threading

PROTOCOL = 1


class BackendError(Exception):
    """An error reply of the driver, or a driver that cannot answer."""

    def __init__(self, message, code=None, transient=False):
        super().__init__(message)
        self.message, self.code, self.transient = message, code, transient


def _finite_list(value, n, what):
    if (not isinstance(value, list) or len(value) != n
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)):
        raise BackendError(f"{what}: expected {n} finite numbers, got {value!r}")
    return [float(v) for v in value]


class SimBackend:
    def __init__(self, command, timeout_s=30.0):
        self.command = [str(c) for c in command]
        self.timeout_s = float(timeout_s)
        self.lock = threading.Lock()
        self.next_id = 0
        self.broken = None  # the BackendError that ended the conversation
        self.lines = queue.Queue()
        try:
            self.proc = subprocess.Popen(self.command, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                         stderr=None, text=True, encoding="utf-8", bufsize=1)
        except OSError as e:
            raise BackendError(f"cannot start {' '.join(self.command)}: {e}") from None
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()
        try:
            result = self._call("hello", {"protocol": PROTOCOL})
        except BackendError:
            self._kill()
            raise
        if result.get("protocol") != PROTOCOL:
            self._kill()
            raise BackendError(f"the driver speaks protocol {result.get('protocol')!r}, not {PROTOCOL}")
        self.name = result.get("name")
        self.capabilities = result.get("capabilities")

    def _read(self):
        for line in self.proc.stdout:
            self.lines.put(line)
        self.lines.put(None)  # end of output

    def _exit_status(self):
        try:
            code = self.proc.wait(timeout=1.0)
        except subprocess.TimeoutExpired:
            return "closed its output"
        return f"exited with status {code}" if code >= 0 else f"was killed by signal {-code}"

    def _call(self, method, params=None):
        with self.lock:
            if self.broken is not None:
                raise self.broken
            self.next_id += 1
            request_id = self.next_id
            line = json.dumps({"id": request_id, "method": method, "params": params or {}})
            try:
                self.proc.stdin.write(line + "\n")
                self.proc.stdin.flush()
            except (OSError, ValueError) as e:
                self.broken = BackendError(f"driver {self._exit_status()} (writing `{method}`: {e})")
                raise self.broken from None
            while True:
                try:
                    reply_line = self.lines.get(timeout=self.timeout_s)
                except queue.Empty:
                    self.broken = BackendError(f"no reply to `{method}` within {self.timeout_s} s")
                    raise self.broken from None
                if reply_line is None:
                    self.broken = BackendError(f"driver {self._exit_status()} during `{method}`")
                    raise self.broken
                try:
                    reply = json.loads(reply_line)
                except ValueError:
                    self.broken = BackendError(f"malformed reply to `{method}`: {reply_line.strip()[:200]!r}")
                    raise self.broken from None
                if not isinstance(reply, dict) or not isinstance(reply.get("id"), int):
                    self.broken = BackendError(f"malformed reply to `{method}`: {reply_line.strip()[:200]!r}")
                    raise self.broken
                if reply["id"] != request_id:
                    continue  # an answer to a request that timed out earlier
                error = reply.get("error")
                if error is not None:
                    if not isinstance(error, dict):
                        error = {"message": str(error)}
                    raise BackendError(str(error.get("message", "")), error.get("code"), bool(error.get("transient")))
                result = reply.get("result")
                return result if isinstance(result, dict) else {}

    def move_joints(self, cw_id, q):
        self._call("move_joints", {"cw_id": int(cw_id), "q_deg": [float(v) for v in q]})

    def apply_wrench(self, w):
        self._call("apply_wrench", {"wrench": [float(v) for v in w]})

    def release_wrench(self):
        self._call("release_wrench")

    def read_wrench(self):
        return _finite_list(self._call("read_wrench").get("wrench"), 6, "read_wrench")

    def read_joints(self):
        return _finite_list(self._call("read_joints").get("q_deg"), 6, "read_joints")

    def measure(self):
        result = self._call("measure")
        out = {"position_mm": _finite_list(result.get("position_mm"), 3, "measure")}
        if result.get("measured_at_us") is not None:
            out["measured_at_us"] = int(result["measured_at_us"])
        if result.get("sigma_mm") is not None:
            out["sigma_mm"] = _finite_list(result["sigma_mm"], 3, "measure sigma_mm")
        return out

    def shutdown(self):
        """Asks the driver to exit and waits for it (kills it after 5 s). Safe to call twice."""
        if self.proc.poll() is None and self.broken is None:
            try:
                self._call("shutdown")
            except BackendError:
                pass
        with self.lock:
            if self.broken is None:
                self.broken = BackendError("the backend was shut down")
            try:
                self.proc.stdin.close()
            except OSError:
                pass
        try:
            self.proc.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            self._kill()

    def _kill(self):
        if self.proc.poll() is None:
            self.proc.kill()
        try:
            self.proc.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            pass
