#!/usr/bin/env python3
"""ABB Robot Web Services emulator for egcal's lab-driver tests (Python 3.11, standard library only).

RwsEmulator(version=1|2, faults=..., backend=...) serves an ABB controller's Robot Web Services on
127.0.0.1 (port 0 = ephemeral; see .port) in its own threads, as in notes/i18-protocols.md section 2:

  RWS 1.0 (IRC5, RobotWare 6): HTTP, Digest auth (MD5, qop="auth"). The first authenticated
    response sets the session cookies `-http-session-` and `ABBCX`; a request carrying a live
    `-http-session-` cookie needs no Authorization (one without it, or with a dead one, makes a new
    session). `?json=1` (or `&json=1`) answers JSON (`_embedded._state[0]`, errors
    `_embedded.status`), otherwise XHTML. Actions are `?action=...`.
  RWS 2.0 (OmniCore, RobotWare 7): HTTPS with a self-signed certificate made at start by
    /usr/bin/openssl, Basic auth on every request, session cookies as in 1.0 (a request without a
    live one makes a new session). Every GET must accept `application/hal+json;v=2.0` (else 406),
    every POST/PUT/DELETE must send `Content-Type: application/x-www-form-urlencoded;v=2.0` (else
    415). JSON only: top-level `state[]` and `status` (errors: `status` alone). Actions are path
    segments.

Both versions count sessions (503 when `max_sessions` are open and a request would make another;
sessions idle for `session_timeout_s` expire) and keep mastership per session and per domain (v1
cfg, motion, rapid; v2 edit, motion). `GET /logout` ends the session and frees its mastership.

Resources                                       RWS 1.0 path                                   RWS 2.0 path
  joints of ROB_1 (GET)                         /rw/motionsystem/mechunits/ROB_1/jointtarget   same
  controller state (GET; POST ctrl-state=...)   /rw/panel/ctrlstate[?action=setctrlstate]      /rw/panel/ctrl-state
  operation mode (GET)                          /rw/panel/opmode                               same
  RAPID execution (GET; POST start/stop/resetpp) /rw/rapid/execution[?action=start]            /rw/rapid/execution[/start]
  RAPID symbol (GET; POST value=...)            /rw/rapid/symbol/data/RAPID/T_ROB1/EgcalServer/V[?action=set]
                                                                               /rw/rapid/symbol/RAPID/T_ROB1/EgcalServer/V/data
  mastership (POST request/release; GET status) /rw/mastership[/D]?action=request|release     /rw/mastership[/D]/request|release
  logout (GET)                                  /logout                                        same
The module may be left out of a symbol path (RAPID/T_ROB1/V); task, module and symbol names are
matched without regard to case, as RAPID does.

RAPID program (module EgcalServer of task T_ROB1; notes section 2.4): PERS jointtarget egc_target,
speeddata egc_speed, nums egc_cmd, egc_done, egc_err, egc_cw_id. When a write of egc_cmd or
egc_done, a ctrl-state=motoron or an execution start finds egc_cmd <> egc_done with the motors on,
the mode AUTO and the program running (the faults included) and no move under way, the program
sets egc_err := 0, takes egc_target and egc_cw_id and, after `move_time_s` (in a thread), moves
(backend.move_joints(egc_cw_id, q) when a backend is given, else it stores q) and sets egc_done :=
egc_cmd (its value then, as the RAPID of the notes does). A target outside `joint_limits` does not
move: egc_err := 41, egc_done := egc_cmd (a backend error: egc_err := 42). A command that finds the
robot not ready waits for the next of those events (writes of egc_target or egc_cw_id never start
a move). The jointtarget resource reads backend.read_joints() once the backend has been moved (the
stored joints before: the simulator has no joints before its first move), else the stored joints.

Faults (device "rws" of the fault file; `times` counts the requests a fault affects):
  no_reply  hold_s         no answer; the connection stays open until the client closes it or hold_s (30) pass
  late_reply  delay_s      answer after delay_s (1.0) seconds
  die                      os._exit(3) as soon as a request arrives
  pool_exhausted           503 on every request that would open a session
  mastership_held          403 (held by someone else) on a mastership request
  motors_off | guard_stop | emergency_stop
                           ctrlstate motoroff | guardstop | emergencystop on GET ctrlstate, and no move
                           (nor execution start) for a request that would start one
  manual_mode              opmode MANR on GET opmode, and no move
  execution_stopped        ctrlexecstate "stopped" on GET execution, and no move
  never_done               the program takes no command (egc_done never catches up, nothing moves)
  joint_offset  offset_deg the jointtarget reads the true joints + offset_deg (0.5) on every axis
  radians                  the jointtarget reports radians instead of degrees
"""
import base64
import hashlib
import json
import math
import os
import re
import secrets
import shutil
import socket
import ssl
import subprocess
import sys
import tempfile
import threading
import time
from collections import OrderedDict
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import parse_qs, unquote, unquote_plus, urlsplit
from xml.sax.saxutils import escape, quoteattr

HOST = "127.0.0.1"
OPENSSL = "/usr/bin/openssl"
TASK, MODULE = "T_ROB1", "EgcalServer"
EAX_NONE = 9e9  # an external axis that is not there

# RWS return codes (notes section 2.1 and the abb-rws-client fixtures).
OK_CODE = 294912  # SYS_CTRL_S_OK
HELD_CODE = -1073445862  # "Requested resource is held by someone else" (403)
NOT_FOUND_CODE = -1073414146  # "Resource not found" (404), "Symbol not found" (v1, 400)
SYMBOL_NOT_FOUND_V2 = -1073442816  # "Symbol not found" (v2, 404)
NO_MASTERSHIP_V2 = -1073445859  # "The user does not have required mastership for the operation." (v2)
WRONG_STATE_CODE = -1073442809  # execution start in the wrong state (400)
INVALID_CODE = -1073442813  # "parameter is invalid or missing" (400)
NO_CODE = -1  # transport-level errors (401, 405, 406, 415, 500, 503): no RWS code known

ERR_JOINT_LIMIT = 41  # egc_err when the target is outside the joint limits
ERR_BACKEND = 42  # egc_err when the backend refused the move

_NUM = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")


def _default_log(message):
    print(f"rws_emulator: {message}", file=sys.stderr, flush=True)


class _NoFaults:
    def check(self, device):
        return self

    def take(self, kind):
        return None


def format_num(v):
    """A RAPID num literal: integers without a point, else up to 10 significant digits."""
    if v == EAX_NONE:
        return "9E+09"
    if float(v).is_integer() and abs(v) < 1e15:
        return str(int(v))
    return format(v, ".10g").upper()


def parse_num(text):
    text = text.strip()
    if not _NUM.fullmatch(text):
        raise ValueError(f"not a num: {text!r}")
    return float(text)


def parse_list(text, n):
    text = text.strip()
    if not (text.startswith("[") and text.endswith("]")):
        raise ValueError(f"not an aggregate: {text!r}")
    items = text[1:-1].split(",")
    if len(items) != n:
        raise ValueError(f"expected {n} components, got {len(items)}")
    return [parse_num(item) for item in items]


def parse_jointtarget(text):
    m = re.fullmatch(r"\s*\[\s*(\[[^\[\]]*\])\s*,\s*(\[[^\[\]]*\])\s*\]\s*", text)
    if not m:
        raise ValueError(f"not a jointtarget: {text!r}")
    return [parse_list(m.group(1), 6), parse_list(m.group(2), 6)]


def format_jointtarget(value):
    robax, extax = value
    return "[[" + ",".join(format_num(v) for v in robax) + "],[" + ",".join(format_num(v) for v in extax) + "]]"


class Symbol:
    TYPES = {
        "num": (parse_num, format_num),
        "jointtarget": (parse_jointtarget, format_jointtarget),
        "speeddata": (lambda t: parse_list(t, 4), lambda v: "[" + ",".join(format_num(x) for x in v) + "]"),
    }

    def __init__(self, name, rapid_type, value):
        self.name, self.type, self.value = name, rapid_type, value

    def text(self):
        return self.TYPES[self.type][1](self.value)

    def parse(self, text):
        return self.TYPES[self.type][0](text)


class Session:
    def __init__(self, number):
        self.number = number
        self.cookie = f"{number}::http.session::{secrets.token_hex(12)}"
        self.abbcx = str(number)
        self.last_used = time.monotonic()


class RwsError(Exception):
    """An error answer: HTTP status, RWS code, message, extra headers."""

    def __init__(self, status, code, msg, headers=()):
        super().__init__(msg)
        self.status, self.code, self.msg, self.headers = status, code, msg, list(headers)


def make_certificate(directory):
    key, cert = os.path.join(directory, "key.pem"), os.path.join(directory, "cert.pem")
    subprocess.run([OPENSSL, "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1",
                    "-subj", "/CN=localhost", "-keyout", key, "-out", cert],
                   check=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    return key, cert


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    ssl_context = None

    def finish_request(self, request, client_address):
        if self.ssl_context is None:
            return super().finish_request(request, client_address)
        request.settimeout(10.0)
        try:  # the TLS handshake runs in the request's thread, not in the accept loop
            tls = self.ssl_context.wrap_socket(request, server_side=True)
        except (ssl.SSLError, OSError) as e:
            self.emulator.log(f"rws: TLS handshake with {client_address[0]}:{client_address[1]} failed: {e}")
            return
        try:
            self.RequestHandlerClass(tls, client_address, self)
        finally:
            try:
                tls.close()
            except OSError:
                pass


class RwsEmulator:
    def __init__(self, version=1, faults=None, backend=None, *, user="Default User", password="robotics",
                 realm="validusers@robapi.abb", max_sessions=70, move_time_s=0.02, joint_limits=None,
                 session_timeout_s=300.0, log=None, host=HOST, port=0):
        if version not in (1, 2):
            raise ValueError(f"RWS version must be 1 or 2, not {version!r}")
        self.version, self.backend = version, backend
        self.user, self.password, self.realm = user, password, realm
        self.max_sessions, self.move_time_s = int(max_sessions), float(move_time_s)
        self.session_timeout_s = float(session_timeout_s)
        limits = joint_limits if joint_limits is not None else [(-180.0, 180.0)] * 6
        self.joint_limits = [(float(lo), float(hi)) for lo, hi in limits]
        if len(self.joint_limits) != 6:
            raise ValueError("joint_limits needs 6 (min, max) pairs")
        self.log = log or _default_log
        if isinstance(faults, (str, os.PathLike)):
            sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
            from cell_emulator import Faults
            faults = Faults(os.fspath(faults))
        self.faults = faults if faults is not None else _NoFaults()
        self.domains = ("cfg", "motion", "rapid") if version == 1 else ("edit", "motion")
        self.rapid_domain = "rapid" if version == 1 else "edit"

        self.lock = threading.RLock()
        self.stop = threading.Event()
        self.sessions = {}  # cookie -> Session
        self.session_count = 0
        self.masters = {}  # domain -> cookie of the session that holds it
        self.nonces = OrderedDict()  # Digest nonces handed out
        self.ctrlstate, self.opmode, self.execstate, self.cycle = "motoron", "AUTO", "running", "forever"
        self.q = [0.0, 0.0, 0.0, 0.0, 30.0, 0.0]
        self.moving, self.backend_moved = False, False
        self.symbols = {s.name.lower(): s for s in (
            Symbol("egc_target", "jointtarget", [list(self.q), [EAX_NONE] * 6]),
            Symbol("egc_speed", "speeddata", [50.0, 30.0, 5000.0, 1000.0]),
            Symbol("egc_cmd", "num", 0.0),
            Symbol("egc_done", "num", 0.0),
            Symbol("egc_err", "num", 0.0),
            Symbol("egc_cw_id", "num", 0.0),
            # CJointT() right after the move, as the RAPID module records it for the
            # driver's in-position check: the target the servo settled on (reading
            # it does not consume the simulator's encoder-noise draws).
            Symbol("egc_reached", "jointtarget", [list(self.q), [EAX_NONE] * 6]),
        )}

        context = None
        if version == 2:
            # The certificate before the socket. The context holds it once loaded, so
            # its files go at once: a test that kills the emulator leaves nothing in /tmp.
            tmpdir = tempfile.mkdtemp(prefix="rws_emulator_")
            try:
                key, cert = make_certificate(tmpdir)
                context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
                context.load_cert_chain(cert, key)
            finally:
                shutil.rmtree(tmpdir, ignore_errors=True)
        self.server = _Server((host, port), _RwsHandler, bind_and_activate=True)
        self.server.emulator = self
        self.server.ssl_context = context
        self.scheme = "https" if version == 2 else "http"
        self.port = self.server.server_address[1]
        self.thread = None

    # ----------------------------------------------------------------- lifecycle
    def start(self):
        self.thread = threading.Thread(target=self.server.serve_forever, kwargs={"poll_interval": 0.2}, daemon=True)
        self.thread.start()
        self.log(f"rws: RWS {self.version}.0 on {self.scheme}://{HOST}:{self.port}/")
        return self

    def close(self):
        self.stop.set()
        if self.thread is not None:
            self.server.shutdown()
            self.thread.join(timeout=2.0)
        self.server.server_close()

    def die(self):
        self.log("rws: fault die, exiting with status 3")
        os._exit(3)

    # ----------------------------------------------------------------- sessions and authentication
    def purge_sessions(self):
        now = time.monotonic()
        for cookie, s in list(self.sessions.items()):
            if now - s.last_used > self.session_timeout_s:
                self.log(f"rws: session {s.number} expired after {self.session_timeout_s} s idle")
                self.end_session(cookie)

    def end_session(self, cookie):
        self.sessions.pop(cookie, None)
        for domain, holder in list(self.masters.items()):
            if holder == cookie:
                del self.masters[domain]

    def challenge(self):
        nonce = secrets.token_hex(16)
        self.nonces[nonce] = time.monotonic()
        while len(self.nonces) > 4096:
            self.nonces.popitem(last=False)
        return (f'Digest realm="{self.realm}", domain="{HOST}:{self.port}", qop="auth", nonce="{nonce}", '
                f'opaque="{hashlib.md5(self.realm.encode()).hexdigest()}", algorithm=MD5, stale=FALSE')

    def digest_ok(self, header, method, path):
        fields = dict((k.lower(), v1 if v1 else v2) for k, v1, v2 in
                      re.findall(r'(\w+)\s*=\s*(?:"((?:[^"\\]|\\.)*)"|([^\s,]*))', header))
        user, nonce, uri, response = (fields.get(k) for k in ("username", "nonce", "uri", "response"))
        if user != self.user or nonce not in self.nonces or not uri or not response:
            return False
        if fields.get("realm") != self.realm or fields.get("algorithm", "MD5").upper() != "MD5":
            return False
        if urlsplit(uri).path != urlsplit(path).path:
            return False
        md5 = lambda s: hashlib.md5(s.encode()).hexdigest()
        ha1, ha2 = md5(f"{self.user}:{self.realm}:{self.password}"), md5(f"{method}:{uri}")
        qop = fields.get("qop")
        if qop == "auth":
            expected = md5(f"{ha1}:{nonce}:{fields.get('nc', '')}:{fields.get('cnonce', '')}:auth:{ha2}")
        elif qop is None:
            expected = md5(f"{ha1}:{nonce}:{ha2}")
        else:
            return False
        return secrets.compare_digest(expected, response.lower())

    def basic_ok(self, header):
        try:
            scheme, token = header.split(None, 1)
            user, _, password = base64.b64decode(token.strip(), validate=True).decode("utf-8").partition(":")
        except (ValueError, UnicodeDecodeError):
            return False
        return scheme.lower() == "basic" and user == self.user and password == self.password

    def check_basic(self, headers):
        if not self.basic_ok(headers.get("Authorization", "")):
            raise RwsError(401, NO_CODE, "Unauthorized: Basic credentials required on every request",
                           [("WWW-Authenticate", f'Basic realm="{self.realm}"')])

    def authenticate(self, method, path, headers, fx):
        """The request's Session and whether it is new, or an RwsError (401, 503)."""
        cookies = {}
        for header in headers.get_all("Cookie") or []:
            for part in header.split(";"):
                name, eq, value = part.strip().partition("=")
                if eq:
                    cookies[name.strip()] = value.strip().strip('"')
        authorization = headers.get("Authorization", "")
        with self.lock:
            self.purge_sessions()
            if self.version == 2:
                self.check_basic(headers)
            session = self.sessions.get(cookies.get("-http-session-", ""))
            if session is not None and cookies.get("ABBCX", session.abbcx) == session.abbcx:
                session.last_used = time.monotonic()
                return session, False
            if self.version == 1 and not (authorization[:7].lower() == "digest " and
                                          self.digest_ok(authorization[7:], method, path)):
                raise RwsError(401, NO_CODE, "Unauthorized", [("WWW-Authenticate", self.challenge())])
            if fx.take("pool_exhausted"):
                raise RwsError(503, NO_CODE, "Too many sessions (fault pool_exhausted)")
            if len(self.sessions) >= self.max_sessions:
                self.log(f"rws: session pool full ({len(self.sessions)} of {self.max_sessions})")
                raise RwsError(503, NO_CODE, f"Too many sessions ({self.max_sessions} open)")
            self.session_count += 1
            session = Session(self.session_count)
            self.sessions[session.cookie] = session
            self.log(f"rws: session {session.number} opened ({len(self.sessions)} open)")
            return session, True

    # ----------------------------------------------------------------- controller state
    def effective_ctrlstate(self, fx):
        for kind, state in (("emergency_stop", "emergencystop"), ("guard_stop", "guardstop"),
                            ("motors_off", "motoroff")):
            if fx.take(kind):
                return state
        return self.ctrlstate

    def effective_opmode(self, fx):
        return "MANR" if fx.take("manual_mode") else self.opmode

    def effective_execstate(self, fx):
        return "stopped" if fx.take("execution_stopped") else self.execstate

    def joints(self, fx):
        """The joints the jointtarget resource reports, in degrees unless the radians fault is on."""
        if self.backend is not None and self.backend_moved:
            q = list(self.backend.read_joints())  # a BackendError becomes a 500
        else:
            with self.lock:
                q = list(self.q)
        if f := fx.take("joint_offset"):
            offset = float(f.get("offset_deg", 0.5))
            q = [v + offset for v in q]
        if fx.take("radians"):
            q = [math.radians(v) for v in q]
        return q

    def kick(self, fx):
        """The RAPID loop: start a move if egc_cmd <> egc_done and the robot can move."""
        with self.lock:
            cmd, done = self.symbols["egc_cmd"].value, self.symbols["egc_done"].value
            if self.moving or cmd == done:
                return
            ctrl = self.effective_ctrlstate(fx)
            mode = self.effective_opmode(fx) if ctrl == "motoron" else self.opmode
            execution = self.effective_execstate(fx) if ctrl == "motoron" and mode == "AUTO" else self.execstate
            if ctrl != "motoron" or mode != "AUTO" or execution != "running":
                self.log(f"rws: RAPID loop waits: egc_cmd {format_num(cmd)} <> egc_done {format_num(done)}, "
                         f"but ctrlstate {ctrl}, opmode {mode}, execution {execution}")
                return
            if fx.take("never_done"):
                self.log(f"rws: RAPID loop does not take egc_cmd {format_num(cmd)} (fault never_done)")
                return
            self.moving = True
            self.symbols["egc_err"].value = 0.0
            target = list(self.symbols["egc_target"].value[0])
            cw_id = int(round(self.symbols["egc_cw_id"].value))
        self.log(f"rws: RAPID loop takes egc_cmd {format_num(cmd)}: MoveAbsJ to {target} (cw_id {cw_id})")
        threading.Thread(target=self.move, args=(target, cw_id), daemon=True).start()

    def move(self, target, cw_id):
        time.sleep(self.move_time_s)
        err = 0
        outside = [f"j{i + 1} = {v}" for i, (v, (lo, hi)) in enumerate(zip(target, self.joint_limits))
                   if not lo <= v <= hi]
        if outside:
            err = ERR_JOINT_LIMIT
            self.log(f"rws: MoveAbsJ refused, outside the joint limits: {', '.join(outside)}; egc_err := {err}")
        elif self.backend is not None:
            try:
                self.backend.move_joints(cw_id, target)
            except Exception as e:  # BackendError, or a backend that broke
                err = ERR_BACKEND
                self.log(f"rws: backend move_joints failed: {e}; egc_err := {err}")
        with self.lock:
            if not err:
                self.q = list(target)
                self.backend_moved = self.backend is not None
                self.symbols["egc_reached"].value = [list(target), [EAX_NONE] * 6]
            self.symbols["egc_err"].value = float(err)
            self.symbols["egc_done"].value = self.symbols["egc_cmd"].value
            self.moving = False
            done = self.symbols["egc_done"].value
        self.log(f"rws: RAPID loop done: egc_done := {format_num(done)}, egc_err := {err}")

    # ----------------------------------------------------------------- requests
    def handle(self, request, method, path, query, body, fx):
        """The routed request: (status, state items or None, base path) or an RwsError."""
        session, method = request.session, method.upper()
        segments = [s for s in path.split("/") if s]
        action = (query.get("action") or [None])[0] if self.version == 1 else None
        form = self.parse_form(body)

        def only(*allowed):
            if method not in allowed:
                raise RwsError(405, NO_CODE, f"Method {method} not allowed on {path}",
                               [("Allow", ", ".join(allowed))])

        if path == "/logout":
            only("GET")
            with self.lock:
                self.end_session(session.cookie)
            request.logout = True
            self.log(f"rws: session {session.number} logged out ({len(self.sessions)} open)")
            return 200, [], "/"
        if path == "/rw/motionsystem/mechunits/ROB_1/jointtarget":
            only("GET")
            q = self.joints(fx)
            item = {"_type": "ms-jointtarget", "_title": "ROB_1"}
            item.update({f"rax_{i + 1}": f"{v:.4f}" for i, v in enumerate(q)})
            item.update({f"eax_{c}": "9E+09" for c in "abcdef"})
            return 200, [item], path
        if path == ("/rw/panel/ctrlstate" if self.version == 1 else "/rw/panel/ctrl-state"):
            only("GET", "POST")
            if method == "GET":
                return 200, [{"_type": "pnl-ctrlstate", "_title": segments[-1], "ctrlstate": self.effective_ctrlstate(fx)}], path
            if self.version == 1 and action != "setctrlstate":
                raise RwsError(400, INVALID_CODE, f"action {action!r} is invalid or missing")
            state = form.get("ctrl-state")
            if state not in ("motoron", "motoroff"):
                raise RwsError(400, INVALID_CODE, f"ctrl-state {state!r} is invalid or missing")
            with self.lock:
                self.ctrlstate = state
            self.log(f"rws: ctrlstate := {state}")
            self.kick(fx)
            return 204, None, path
        if path == "/rw/panel/opmode":
            only("GET")
            return 200, [{"_type": "pnl-opmode", "_title": "opmode", "opmode": self.effective_opmode(fx)}], path
        if path == "/rw/rapid/execution" or (self.version == 2 and len(segments) == 4 and path.startswith("/rw/rapid/execution/")):
            if self.version == 1:
                only("GET", "POST")
                verb = action if method == "POST" else None
            else:
                only("POST" if len(segments) == 4 else "GET")
                verb = segments[3] if len(segments) == 4 else None
            if method == "GET":
                return 200, [{"_type": "rap-execution", "_title": "execution",
                              "ctrlexecstate": self.effective_execstate(fx), "cycle": self.cycle}], path
            return self.execution(verb, form, fx, path)
        if path.startswith("/rw/rapid/symbol/"):
            return self.symbol(request, method, segments, action, form, fx, only, path)
        if segments[:2] == ["rw", "mastership"]:
            return self.mastership(session, method, segments[2:], action, fx, only, path)
        raise RwsError(404, NOT_FOUND_CODE, "Resource not found")

    def parse_form(self, body):
        form = {}
        for part in body.split("&"):
            name, eq, value = part.partition("=")
            if eq:
                form[unquote_plus(name).strip()] = value  # values are decoded by their users
        return {k: (unquote_plus(v) if k != "value" else v) for k, v in form.items()}

    def execution(self, verb, form, fx, path):
        if verb not in ("start", "stop", "resetpp"):
            if self.version == 1:
                raise RwsError(400, INVALID_CODE, f"action {verb!r} is invalid or missing")
            raise RwsError(404, NOT_FOUND_CODE, "Resource not found")
        if verb == "start":
            ctrl = self.effective_ctrlstate(fx)
            if ctrl != "motoron":
                raise RwsError(400, WRONG_STATE_CODE, f"cannot start RAPID execution: ctrlstate {ctrl}")
            with self.lock:
                self.execstate = "running"
                if form.get("cycle") in ("once", "forever", "oncedone"):
                    self.cycle = form["cycle"]
            self.log("rws: RAPID execution started")
            self.kick(fx)
        elif verb == "stop":
            with self.lock:
                self.execstate = "stopped"
            self.log("rws: RAPID execution stopped")
        return 204, None, path

    def symbol(self, request, method, segments, action, form, fx, only, path):
        # v1: rw rapid symbol data RAPID T [M] V ; v2: rw rapid symbol RAPID T [M] V data
        if self.version == 1:
            names = segments[4:] if segments[3:4] == ["data"] else None
        else:
            names = segments[3:-1] if segments[-1:] == ["data"] else None
        if not names or names[0] != "RAPID" or len(names) not in (3, 4):
            raise RwsError(404, NOT_FOUND_CODE, "Resource not found")
        only("GET", "POST")
        task, var = names[1], names[-1]
        module = names[2] if len(names) == 4 else None
        symbol = self.symbols.get(var.lower())
        if (task.lower() != TASK.lower() or (module is not None and module.lower() != MODULE.lower())
                or symbol is None):
            if self.version == 1:
                raise RwsError(400, NOT_FOUND_CODE, "Symbol not found")
            raise RwsError(404, SYMBOL_NOT_FOUND_V2, "Symbol not found")
        title = f"RAPID/{TASK}/{MODULE}/{symbol.name}"
        base = f"/rw/rapid/symbol/data/RAPID/{TASK}/{MODULE}/" if self.version == 1 else path
        if method == "GET":
            with self.lock:
                text = symbol.text()
            return 200, [{"_type": "rap-data", "_title": title, "value": text}], base
        if self.version == 1 and action != "set":
            raise RwsError(400, INVALID_CODE, f"action {action!r} is invalid or missing")
        with self.lock:
            if self.masters.get(self.rapid_domain) != request.session.cookie:
                code = NOT_FOUND_CODE if self.version == 1 else NO_MASTERSHIP_V2
                raise RwsError(400, code, f"writing {symbol.name} needs {self.rapid_domain} mastership held by this session")
        raw = form.get("value")
        if raw is None:
            raise RwsError(400, INVALID_CODE, "value is invalid or missing")
        value, problem = None, None
        for candidate in dict.fromkeys((unquote(raw), unquote_plus(raw))):  # raw '+' kept first, then form '+'
            try:
                value = symbol.parse(candidate)
                break
            except ValueError as e:
                problem = e
        if value is None:
            raise RwsError(400, INVALID_CODE, f"value for {symbol.type} {symbol.name} is invalid: {problem}")
        with self.lock:
            symbol.value = value
            text = symbol.text()
        self.log(f"rws: {symbol.name} := {text}")
        if symbol.name in ("egc_cmd", "egc_done"):
            self.kick(fx)
        return 204, None, path

    def mastership(self, session, method, rest, action, fx, only, path):
        if self.version == 1:
            if len(rest) > 1 or (rest and rest[0] not in self.domains):
                raise RwsError(404, NOT_FOUND_CODE, "Resource not found")
            domains = [rest[0]] if rest else list(self.domains)
            if method == "GET" and rest:
                return self.mastership_status(session, rest[0], path)
            only("POST")
            verb = action
            if verb not in ("request", "release"):
                raise RwsError(400, INVALID_CODE, f"action {verb!r} is invalid or missing")
        else:
            if len(rest) == 1 and rest[0] in self.domains and method == "GET":
                return self.mastership_status(session, rest[0], path)
            if len(rest) == 1 and rest[0] in ("request", "release"):
                domains, verb = list(self.domains), rest[0]
            elif len(rest) == 2 and rest[0] in self.domains and rest[1] in ("request", "release"):
                domains, verb = [rest[0]], rest[1]
            else:
                raise RwsError(404, NOT_FOUND_CODE, "Resource not found")
            only("POST")
        with self.lock:
            if verb == "request":
                if fx.take("mastership_held"):
                    raise RwsError(403, HELD_CODE, "Requested resource is held by someone else (fault mastership_held)")
                for d in domains:
                    holder = self.masters.get(d)
                    if holder is not None and holder != session.cookie:
                        other = self.sessions.get(holder)
                        raise RwsError(403, HELD_CODE, f"Requested resource is held by someone else "
                                       f"({d} by session {other.number if other else '?'})")
                for d in domains:
                    self.masters[d] = session.cookie
            else:
                for d in domains:
                    holder = self.masters.get(d)
                    if holder is not None and holder != session.cookie:
                        raise RwsError(403, HELD_CODE, f"Requested resource is held by someone else ({d})")
                for d in domains:
                    self.masters.pop(d, None)
        self.log(f"rws: session {session.number} {verb}s mastership {', '.join(domains)}")
        return 204, None, path

    def mastership_status(self, session, domain, path):
        with self.lock:
            holder = self.masters.get(domain)
        item = {"_type": "msh-resource", "_title": domain, "uid": "", "location": "", "application": "",
                "mastership": "nomaster" if holder is None else "remote",
                "mastershipheldbyme": "TRUE" if holder == session.cookie else "FALSE"}
        return 200, [item], path


def _media(value):
    """(type, {param: value}) of one media type, lower case, without spaces."""
    parts = [p.strip().lower() for p in value.split(";")]
    params = {}
    for p in parts[1:]:
        k, _, v = p.partition("=")
        params[k.strip()] = v.strip().strip('"')
    return parts[0], params


class _RwsHandler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    server_version = "RWS-emulator/1.0"
    timeout = 120  # an idle keep-alive connection is closed after this

    def log_message(self, format, *args):
        pass  # one line per request is logged by handle_request

    def do_GET(self):
        self.handle_request("GET")

    def do_POST(self):
        self.handle_request("POST")

    def do_PUT(self):
        self.handle_request("PUT")

    def do_DELETE(self):
        self.handle_request("DELETE")

    def handle_request(self, method):
        emu = self.server.emulator
        self.session, self.logout, self.json = None, False, emu.version == 2
        try:
            length = int(self.headers.get("Content-Length") or 0)
            body = self.rfile.read(length).decode("utf-8", "replace") if length > 0 else ""
            parts = urlsplit(self.path)
            path = unquote(parts.path).rstrip("/") or "/"
            query = parse_qs(parts.query, keep_blank_values=True)
            self.json = emu.version == 2 or query.get("json", ["0"])[-1] == "1"
            peer = f"{self.client_address[0]}:{self.client_address[1]}"
            emu.log(f"rws: {method} {self.path}{' ' + body if body else ''} from {peer}")
            fx = emu.faults.check("rws")
            if fx.take("die"):
                emu.die()
            if f := fx.take("no_reply"):
                self.hold(float(f.get("hold_s", 30.0)))
                return
            if f := fx.take("late_reply"):
                time.sleep(float(f.get("delay_s", 1.0)))
            new = False
            try:
                if emu.version == 2:
                    emu.check_basic(self.headers)
                    self.check_v2_headers(method)
                self.session, new = emu.authenticate(method, self.path, self.headers, fx)
                status, items, base = emu.handle(self, method, path, query, body, fx)
            except (RwsError, Exception) as e:
                if not isinstance(e, RwsError):  # a backend failure or a bug: answer, and keep serving
                    emu.log(f"rws: error handling {method} {self.path}: {type(e).__name__}: {e}")
                    e = RwsError(500, NO_CODE, f"{type(e).__name__}: {e}")
                self.send_error_envelope(e, self.cookies(new))
                return
            cookies = self.cookies(new)
            if status == 204:
                self.send(204, None, b"", cookies)
            else:
                self.send_state(status, items, base, cookies)
        except Exception as e:
            emu.log(f"rws: error handling {method} {self.path}: {type(e).__name__}: {e}")
            self.close_connection = True

    def cookies(self, new):
        """Set-Cookie headers: the session's when it was opened by this request, expired ones at logout."""
        if self.logout:
            return [("Set-Cookie", "-http-session-=; Path=/; Max-Age=0"), ("Set-Cookie", "ABBCX=; Path=/; Max-Age=0")]
        if new:
            return [("Set-Cookie", f"-http-session-={self.session.cookie}; Path=/; HttpOnly"),
                    ("Set-Cookie", f"ABBCX={self.session.abbcx}; Path=/; HttpOnly")]
        return []

    def check_v2_headers(self, method):
        if method == "GET":
            accepted = [_media(v) for v in (self.headers.get("Accept") or "").split(",") if v.strip()]
            if not any(t == "application/hal+json" and p.get("v") == "2.0" for t, p in accepted):
                raise RwsError(406, NO_CODE, "Not Acceptable: send Accept: application/hal+json;v=2.0")
        else:
            t, p = _media(self.headers.get("Content-Type") or "")
            if t != "application/x-www-form-urlencoded" or p.get("v") != "2.0":
                raise RwsError(415, NO_CODE, "Unsupported Media Type: send Content-Type: "
                                             "application/x-www-form-urlencoded;v=2.0")

    # ----------------------------------------------------------------- answers
    def href(self, path):
        emu = self.server.emulator
        return f"{emu.scheme}://{HOST}:{emu.port}{path}"

    def send_state(self, status, items, base, cookies):
        emu = self.server.emulator
        if emu.version == 1:
            base_path = base if base.endswith("/") else base.rsplit("/", 1)[0] + "/"
            self_rel = "" if base.endswith("/") else base.rsplit("/", 1)[1]
        else:
            base_path, self_rel = (base if base.endswith("/") else base + "/"), ""
        links = {"base": {"href": self.href(base_path)}, "self": {"href": self_rel}}
        if emu.version == 2:
            doc = {"_links": links, "status": {"code": OK_CODE}, "state": items}
            self.send(status, "application/hal+json;v=2.0", json.dumps(doc).encode(), cookies)
        elif self.json:
            doc = {"_links": links, "_embedded": {"_state": items}}
            self.send(status, "application/json", json.dumps(doc).encode(), cookies)
        else:
            lis = "".join(
                f"<li class={quoteattr(i['_type'])} title={quoteattr(i['_title'])}>"
                + "".join(f"<span class={quoteattr(k)}>{escape(str(v))}</span>" for k, v in i.items()
                          if not k.startswith("_"))
                + "</li>" for i in items)
            xhtml = (f'<?xml version="1.0" encoding="utf-8"?><html xmlns="http://www.w3.org/1999/xhtml"><head>'
                     f"<title>rw</title><base href={quoteattr(self.href(base_path))}/></head><body>"
                     f'<div class="state"><a href={quoteattr(self_rel)} rel="self"></a><ul>{lis}</ul></div></body></html>')
            self.send(status, "application/xhtml+xml", xhtml.encode(), cookies)

    def send_error_envelope(self, e, cookies=()):
        emu = self.server.emulator
        base = {"base": {"href": self.href("/")}}
        status = {"code": e.code, "msg": f"{e.msg} code:{e.code} icode:-1"}
        if emu.version == 2:
            body, ctype = json.dumps({"_links": base, "status": status}).encode(), "application/hal+json;v=2.0"
        elif self.json:
            body = json.dumps({"_links": base, "_embedded": {"status": status, "_state": []}}).encode()
            ctype = "application/json"
        else:
            body = (f'<?xml version="1.0" encoding="UTF-8"?><html xmlns="http://www.w3.org/1999/xhtml"><head>'
                    f"<title>rw</title><base href={quoteattr(self.href('/'))}/></head><body><div class=\"status\">"
                    f'<span class="code">{e.code}</span><span class="msg">{escape(status["msg"])}</span>'
                    f"</div></body></html>").encode()
            ctype = "application/xhtml+xml"
        self.send(e.status, ctype, body, e.headers + list(cookies))

    def send(self, status, content_type, body, headers=()):
        self.send_response(status)
        if content_type:
            self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(body)))
        for name, value in headers:
            self.send_header(name, value)
        self.end_headers()
        if body:
            self.wfile.write(body)
        self.server.emulator.log(f"rws: -> {status}{' ' + body.decode('utf-8', 'replace') if status >= 400 else ''}")

    def hold(self, hold_s):
        """Leave the request unanswered until the client closes the connection or hold_s passes."""
        self.close_connection = True
        self.connection.settimeout(0.2)
        deadline = time.monotonic() + hold_s
        while time.monotonic() < deadline and not self.server.emulator.stop.is_set():
            try:
                if not self.connection.recv(4096):
                    return
            except socket.timeout:
                continue
            except (OSError, ssl.SSLError):
                return
