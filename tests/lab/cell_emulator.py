#!/usr/bin/env python3
"""Lab-cell emulator for egcal's lab-driver integration tests (Python 3.11, standard library only).

It emulates, on 127.0.0.1 with ephemeral ports:
  * an ATI Net F/T: RDT over UDP (8-byte requests, 36-byte big-endian records) and
    GET /netftapi2.xml over HTTP, as in notes/i18-protocols.md section 1;
  * egcal's cable-robot controller, as in schemas/cable-robot-udp.md (version 1);
  * an ABB controller's Robot Web Services, version 1.0 (HTTP, Digest) or 2.0 (HTTPS, Basic), with the
    RAPID server loop of module EgcalServer, as in notes/i18-protocols.md section 2 (rws_emulator.py);
  * a Leica laser tracker speaking emScon TPI over TCP (binary, little-endian), as in
    notes/i18-protocols.md section 3 (emscon_emulator.py).
The force sensor reads the wrench that the cable robot currently holds. With --sim-driver, egcal's
simulator (sim_backend.py) is the physics behind all four: the RWS RAPID loop moves it
(move_joints) and the jointtarget reads it (read_joints), SET_WRENCH and RELEASE call its
apply_wrench and release_wrench, each RDT start request reads its read_wrench once, and each
tracker StartMeasurement that sends a measured position calls its measure once. egcal's
campaign calls these in the order of the in-process simulator (move_joints, apply_wrench,
read_wrench, read_joints, measure, release_wrench), so the simulator sees the same sequence.

Behaviour
  Cable robot: SET_WRENCH -> RAMPING for the next 2 STATUS requests, HOLDING on the 3rd (the held
  wrench is then the set-point, and the sensor starts to read it); RELEASE -> RAMPING for 1 STATUS,
  then IDLE with zero wrench. A set-point with |(fx,fy,fz)| > 2000 N or |(mx,my,mz)| > 300 N·m (Euclidean
  norms) or a non-finite value is refused: flag bit 2 in its reply and in later replies until the next
  accepted SET_WRENCH or RELEASE, and the state does not change. 4 cables, 100 N pretension.
  Datagrams of the wrong size, magic, version or command are ignored without a reply.
  Net F/T: one stream slot (the last start wins; stop or bias from anyone ends it), one record per
  1/comrdtrate s (--rdt-rate, default 1000 Hz, reported as <comrdtrate> in netftapi2.xml),
  rdt_sequence from 1 on each start, ft_sequence +7 per record and never reset, counts =
  round((wrench - bias) * 1000000) + noise, status 0 (0xC0000000, error + F/T out of range, if a count
  saturates i32). 0x0042 tares at the current load, 0x0041 does nothing, other commands are ignored.
  The status word's bits (ATI manual 9620-05, Net F/T system status code): 31 error (summary), 30 F/T
  out of range, 29 calibration checksum error, 28 simulated error, 27 gage out of range, 16 monitor
  condition latched (not an error), 5 other error, 3 busy, 2 broken gage, 1 supply voltage out of
  range, 0 temperature out of range.

CLI
  python3 tests/lab/cell_emulator.py --ready-file PATH [--faults FILE] [--seed N]
      [--rws-version {1,2}] [--sim-driver JSON] [--rdt-rate HZ]
      [--reflectors-answer {records,status_first,records_first}]

  When every server is bound, PATH is written atomically (PATH.tmp, then a rename) with
  {"ati_http": port, "ati_rdt": port, "cable_robot": port, "rws": port, "rws_version": 1 or 2,
  "tracker": port, "pid": pid}. The emulator then serves until SIGTERM/SIGINT (exit 0) or a `die` fault (exit 3). It
  logs one line per request and per injected fault to stderr, each prefixed "cell_emulator:".
  --seed (default 0) seeds the +-2-count noise added to the force readings. --rws-version (default
  1) picks RWS 1.0 or 2.0 (user "Default User", password "robotics", at most 70 sessions, a move
  takes 0.02 s, joint limits +-180 deg). --rdt-rate (default 1000) is the Net F/T's RDT output rate
  in Hz. --reflectors-answer (default records) is how the tracker answers GetReflectors (see
  emscon_emulator.py). --sim-driver takes a JSON list, the command of a driver
  speaking schemas/driver-protocol.md, e.g. '["egcal", "sim-driver", "--robot", "r.toml"]'; it is
  started before the servers and shut down at exit (exit 2 if it or the RWS server cannot start). With it:
    * SET_WRENCH (once accepted as today) and RELEASE call apply_wrench / release_wrench; an error
      whose message contains "infeasible" refuses the set-point (flag bit 2, state unchanged), any
      other error puts the controller in FAULT until the next accepted SET_WRENCH or RELEASE. The
      reply's wrench and tensions are still those of the set-point, as without it;
    * an RDT start request reads read_wrench once and every record of it carries that wrench (minus
      the bias, quantised and with the +-2-count noise as now); an error gives status 0x80000020
      (error + other error) and the counts of the cable robot's load;
    * the RAPID loop's moves call move_joints(egc_cw_id, q) and, once moved, the jointtarget reads
      read_joints;
    * the tracker's StartMeasurement result is at measure()'s position_mm (std sigma_mm when given);
      an error gives BasicCommandRT {49, 0} then ErrorResponseT {49, 10009}.
  Without it everything behaves as before (the joints are stored by the RWS emulator, and the
  tracker measures the fixed point (1000, 200, 800) mm).

Fault file (JSON). It is re-read before each request, so rewrite it atomically to change the faults mid-run:
  {"ati": [FAULT, ...], "ati_http": [FAULT, ...], "cable_robot": [FAULT, ...], "rws": [FAULT, ...],
   "tracker": [FAULT, ...]}
  FAULT = {"kind": KIND, "times": N, ...parameters}
  "times" is the number of requests the fault affects. If it is absent or null, the fault affects every request.
  A fault is used up only by requests it can affect: `status` counts RDT start requests, and
  `tension_limit` counts replies sent while HOLDING. The remaining counts are kept in memory, keyed by
  device, index and kind, and start again whenever the file is rewritten (new inode, mtime or content).
  A missing or unparsable file means there are no faults. JSON has no hex literals: give status words
  as integers or as "0x..." strings.

  Any device:
    no_reply               drop the request. On HTTP, the connection stays open without an answer until the
                           client closes it or "hold_s" seconds pass (default 30).
    late_reply   delay_s   answer after delay_s seconds (default 1.0). The cable robot carries out the command
                           at once and only delays the reply.
    die                    os._exit(3) as soon as the request arrives
    malformed              RDT: every record of the request is cut to 30 bytes. Cable robot: "variant" "size"
                           (default; the reply is cut to 100 bytes), "magic" or "version". HTTP: 200 text/xml
                           with a body that is not XML. The request itself is still carried out.
  ati (RDT). Every kind except `die` affects only start requests (0x0002) and the records sent for them,
  whether the request asks for a count or a stream:
    status       word      status word in every record (an int or a "0x..." string; default 0x80000020)
    stalled_sequence       ft_sequence does not advance (it repeats the last value sent)
    backward_sequence      ft_sequence goes down by 7 per record
    rdt_gap                one record is lost before the 2nd record (before the 1st if count is 1):
                           rdt_sequence skips one number and ft_sequence jumps by 14
    stolen       after     stop sending after `after` records (default 1), as if another client
                           had taken the stream
  ati_http:
    force_unit   code, label   report another force unit (default 1, "lbf")
    torque_unit  code, label   report another torque unit (default 4, "Nmm")
    calibration_changed    the first `after` (default 1) netftapi2.xml requests are served normally, then
                           report "calsn" (default "FT54321"), "cpf" (default 2000000) and "cpt"
                           (default unchanged). These HTTP faults change only the XML: the RDT counts
                           always use 1000000 counts per N and per N·m.
  cable_robot:
    estop                  the command is not carried out; the reply has state FAULT and flag bit 3 ("after": the first N requests pass)
    tension_limit          flag bit 1 in replies sent while HOLDING
    never_holds            a STATUS does not advance a ramp, so the state stays RAMPING
    infeasible             SET_WRENCH is refused as infeasible (flag bit 2) whatever its set-point
  rws (every kind counts the requests it affects; details in rws_emulator.py):
    no_reply, late_reply, die   as above (HTTP: no_reply holds the connection, "hold_s" default 30)
    pool_exhausted         503 on every request that would open a session
    mastership_held        403 "held by someone else" on a mastership request
    motors_off, guard_stop, emergency_stop
                           GET ctrlstate reads motoroff / guardstop / emergencystop, and a request that
                           would start a move (or RAPID execution) finds the motors off: nothing moves
    manual_mode            GET opmode reads MANR, and nothing moves
    execution_stopped      GET execution reads ctrlexecstate "stopped", and nothing moves
    never_done             the RAPID loop does not take the command: egc_done never catches up
    joint_offset  offset_deg   the jointtarget reads the true joints + offset_deg (default 0.5) on every axis
    radians                the jointtarget reports radians instead of degrees
  A command that found the robot not ready is taken at the next write of egc_cmd or egc_done,
  ctrl-state=motoron or execution start that finds it ready (a retry writes egc_cmd again).
  tracker (every kind affects and counts only StartMeasurement commands; details in emscon_emulator.py):
    no_reply, late_reply, die   as above (no_reply: neither the BasicCommandRT nor a result)
    beam_lost              RT {49, 0}, then ErrorResponseT {49, 10009 NoStationaryResult} instead of a result
    beam_lost_zeros        a result with status 0 and position (0, 0, 0)
    beam_lost_nan          a result with status 0 and a NaN position
    not_warmed_up          RT status 10012 SensorNotWarmedUp, no result
    malformed              the result's lPacketSize says 156 but only 100 bytes are sent; the connection closes
    wrong_units            the result's lengths in metres instead of millimetres
"""
import argparse
import json
import math
import os
import random
import signal
import socket
import ssl
import struct
import subprocess
import sys
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import parse_qs, urlsplit
from xml.sax.saxutils import escape

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from emscon_emulator import EmsconEmulator  # noqa: E402
from rws_emulator import RwsEmulator  # noqa: E402
from sim_backend import BackendError, SimBackend  # noqa: E402

HOST = "127.0.0.1"
CPF = CPT = 1_000_000  # counts per N / per N·m
I32_MIN, I32_MAX = -(2**31), 2**31 - 1
_log_lock = threading.Lock()


def log(message):
    with _log_lock:
        print(f"cell_emulator: {message}", file=sys.stderr, flush=True)


def die(device):
    log(f"{device}: fault die, exiting with status 3")
    os._exit(3)


def udp_socket():
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind((HOST, 0))
    sock.settimeout(0.2)
    return sock


def udp_serve(sock, stop, handle):
    """Hand every datagram to handle(data, addr) until stop is set."""
    while not stop.is_set():
        try:
            data, addr = sock.recvfrom(2048)
        except socket.timeout:
            continue
        except OSError:
            break
        try:
            handle(data, addr)
        except Exception as e:  # a bad fault parameter must not stop the server
            log(f"error handling a datagram from {addr[0]}:{addr[1]}: {type(e).__name__}: {e}")


def to_counts(values, noise=None):
    """Counts for a wrench in N and N·m, clamped to i32; the second value is True when a count saturated."""
    counts, saturated = [], False
    for i, value in enumerate(values):
        count = round(value * (CPF if i < 3 else CPT)) + (noise.randint(-2, 2) if noise else 0)
        if not I32_MIN <= count <= I32_MAX:
            count, saturated = max(I32_MIN, min(I32_MAX, count)), True
        counts.append(count)
    return counts, saturated


class Faults:
    """The fault file, re-read for every request, with the remaining "times" of each fault."""

    # Kinds whose "after" parameter counts requests: the first `after` requests pass unaffected.
    AFTER_REQUESTS = {"calibration_changed": 1, "estop": 0}

    def __init__(self, path):
        self.path, self.version, self.spec = path, (), {}
        self.left, self.seen, self.generation = {}, {}, 0
        self.lock = threading.Lock()

    def _reload(self):
        if self.path is None:
            return
        try:
            with open(self.path, "rb") as f:
                stat, raw = os.fstat(f.fileno()), f.read()
            version = (stat.st_ino, stat.st_mtime_ns, raw)  # a rewrite with the same content also counts
        except OSError:
            raw, version = b"", None
        if version == self.version:
            return
        self.version, self.left, self.seen = version, {}, {}
        self.generation += 1
        try:
            spec = json.loads(raw) if raw.strip() else {}
        except ValueError as e:
            log(f"faults: cannot parse {self.path} ({e}); no faults")
            spec = {}
        self.spec = spec if isinstance(spec, dict) else {}
        log(f"faults: loaded {json.dumps(self.spec, sort_keys=True)}")

    def check(self, device):
        """Re-read the file; the faults of `device` that still have requests left, as a RequestFaults."""
        with self.lock:
            self._reload()
            active = {}
            for index, fault in enumerate(self.spec.get(device) or []):
                if not isinstance(fault, dict) or not isinstance(fault.get("kind"), str):
                    continue
                key = (device, index, fault["kind"])
                left = self.left.get(key, fault.get("times"))
                if left is None or left > 0:
                    active.setdefault(fault["kind"], (key, fault))
            return RequestFaults(self, device, active, self.generation)

    def use(self, key, fault, generation):
        with self.lock:
            if generation != self.generation:
                return False  # the file changed since the request was checked
            seen = self.seen.get(key, 0)
            self.seen[key] = seen + 1
            if key[2] in self.AFTER_REQUESTS and seen < int(fault.get("after", self.AFTER_REQUESTS[key[2]])):
                return False
            left = self.left.get(key, fault.get("times"))
            if left is not None:
                self.left[key] = left - 1
            return True


class RequestFaults:
    """The faults that may affect one request."""

    def __init__(self, faults, device, active, generation):
        self.faults, self.device, self.active, self.generation = faults, device, active, generation

    def take(self, kind):
        """The fault `kind` if it affects this request (using up one of its times), else None."""
        entry = self.active.get(kind)
        if entry is None or not self.faults.use(entry[0], entry[1], self.generation):
            return None
        log(f"{self.device}: inject fault {json.dumps(entry[1], sort_keys=True)}")
        return entry[1]


class Load:
    """The wrench the cable robot applies (N, N·m) and the sensor's software bias."""

    def __init__(self):
        self.lock = threading.Lock()
        self.applied, self.bias = [0.0] * 6, [0.0] * 6

    def set_applied(self, wrench):
        with self.lock:
            self.applied = [float(v) for v in wrench]

    def get_applied(self):
        with self.lock:
            return list(self.applied)

    def tare(self):
        with self.lock:
            self.bias = list(self.applied)

    def net(self):
        with self.lock:
            return [a - b for a, b in zip(self.applied, self.bias)]

    def get_bias(self):
        with self.lock:
            return list(self.bias)


class Stream:
    """The records answering one RDT start request (count None = until stopped)."""

    def __init__(self, addr, count):
        self.addr, self.count = addr, count
        self.sent = self.rdt_seq = 0
        self.next_t = time.monotonic()
        self.status, self.stalled, self.backward, self.malformed = 0, False, False, False
        self.gap_before = self.stop_after = None
        self.wrench = None  # the backend's reading for this request (None: the cable robot's load)


class AtiRdt:
    """Net F/T RDT server: one stream slot, owned by whoever sent the last start."""

    REQUEST = struct.Struct(">HHI")
    RECORD = struct.Struct(">IIIiiiiii")
    FT_STEP = 7  # 7 kHz internal samples per 1 kHz output record

    def __init__(self, load, faults, seed, stop, backend=None, rate_hz=1000.0):
        self.load, self.faults, self.stop, self.backend = load, faults, stop, backend
        self.period_s = 1.0 / rate_hz  # one record per 1/comrdtrate s
        self.sock = udp_socket()
        self.port = self.sock.getsockname()[1]
        self.cond = threading.Condition()
        self.stream = None
        self.ft_seq = 1_000_000  # device sample counter, never reset
        self.noise = random.Random(seed)

    def serve(self):
        udp_serve(self.sock, self.stop, self.handle)

    def handle(self, data, addr):
        if len(data) != self.REQUEST.size or self.REQUEST.unpack(data)[0] != 0x1234:
            log(f"ati: ignored a {len(data)}-byte datagram from {addr[0]}:{addr[1]} {data[:8].hex()}")
            return
        _, command, count = self.REQUEST.unpack(data)
        log(f"ati: command 0x{command:04x} count {count} from {addr[0]}:{addr[1]}")
        fx = self.faults.check("ati")
        if fx.take("die"):
            die("ati")
        if command == 0x0002:
            if not fx.take("no_reply"):
                self.start(addr, count, fx)
        elif command == 0x0000:
            self.end("stop")
        elif command == 0x0042:
            self.load.tare()
            self.end("bias")
        elif command != 0x0041:
            log(f"ati: command 0x{command:04x} not supported, ignored")

    def start(self, addr, count, fx):
        s = Stream(addr, count or None)
        if self.backend is not None:
            try:
                s.wrench = self.backend.read_wrench()
            except BackendError as e:
                log(f"ati: backend read_wrench failed: {e}")
                s.status |= 0x80000020
        if f := fx.take("late_reply"):
            s.next_t += float(f.get("delay_s", 1.0))
        if f := fx.take("status"):
            word = f.get("word", 0x80000020)
            s.status |= (int(word, 0) if isinstance(word, str) else int(word)) & 0xFFFFFFFF
        s.stalled = fx.take("stalled_sequence") is not None
        s.backward = fx.take("backward_sequence") is not None
        if fx.take("rdt_gap"):
            s.gap_before = 0 if count == 1 else 1
        if f := fx.take("stolen"):
            s.stop_after = int(f.get("after", 1))
        s.malformed = fx.take("malformed") is not None
        with self.cond:
            if self.stream is not None:
                log(f"ati: stream to {self.stream.addr[0]}:{self.stream.addr[1]} replaced")
            self.stream = s
            self.cond.notify()

    def end(self, why):
        with self.cond:
            if self.stream is not None:
                log(f"ati: {why} ends the stream to {self.stream.addr[0]}:{self.stream.addr[1]}")
            self.stream = None
            self.cond.notify()

    def record(self, s):
        if s.gap_before is not None and s.sent == s.gap_before:
            s.rdt_seq += 1  # a record lost on the way: both counters moved on
            self.ft_seq = (self.ft_seq + self.FT_STEP) % 2**32
            s.gap_before = None
        s.rdt_seq += 1
        if not s.stalled:
            step = -self.FT_STEP if s.backward else self.FT_STEP
            self.ft_seq = (self.ft_seq + step) % 2**32
        if s.wrench is not None:
            net = [w - b for w, b in zip(s.wrench, self.load.get_bias())]
        else:
            net = self.load.net()
        counts, saturated = to_counts(net, self.noise)
        status = s.status | (0xC0000000 if saturated else 0)
        data = self.RECORD.pack(s.rdt_seq % 2**32, self.ft_seq, status, *counts)
        return data[:30] if s.malformed else data

    def stream_loop(self):
        with self.cond:
            while not self.stop.is_set():
                s = self.stream
                if s is None:
                    self.cond.wait(0.2)
                    continue
                wait = s.next_t - time.monotonic()
                if wait > 0:
                    self.cond.wait(wait)
                    continue
                try:
                    self.sock.sendto(self.record(s), s.addr)
                except OSError as e:
                    log(f"ati: send to {s.addr[0]}:{s.addr[1]} failed ({e}); stream ended")
                    self.stream = None
                    continue
                s.sent += 1
                s.next_t = max(s.next_t + self.period_s, time.monotonic() - 0.02)
                if s.count is not None and s.sent >= s.count:
                    self.stream = None
                elif s.stop_after is not None and s.sent >= s.stop_after:
                    log(f"ati: stream stolen after {s.sent} records")
                    self.stream = None


class _NetFtHandler(BaseHTTPRequestHandler):
    server_version = "NetFT-emulator/1.0"

    def log_message(self, format, *args):
        pass  # one line per request is logged by do_GET

    def do_GET(self):
        try:
            self.get()
        except Exception as e:  # a bad fault parameter must not leave a traceback without the log prefix
            log(f"ati_http: error handling GET {self.path}: {type(e).__name__}: {e}")
            self.close_connection = True

    def get(self):
        device = self.server.device
        log(f"ati_http: GET {self.path} from {self.client_address[0]}:{self.client_address[1]}")
        fx = device.faults.check("ati_http")
        if fx.take("die"):
            die("ati_http")
        if f := fx.take("no_reply"):
            self.hold(float(f.get("hold_s", 30.0)))
            return
        if f := fx.take("late_reply"):
            time.sleep(float(f.get("delay_s", 1.0)))
        parts = urlsplit(self.path)
        query = parse_qs(parts.query, keep_blank_values=True)
        index = query.pop("index", ["0"])
        if parts.path != "/netftapi2.xml" or query or len(index) != 1 or index[0] not in {str(i) for i in range(16)}:
            self.send(404, "text/plain", b"404 Not Found\n")
            return
        body = device.document(fx)
        if fx.take("malformed"):
            body = b"this is not XML {netft: broken"
        self.send(200, "text/xml", body)

    def send(self, code, content_type, body):
        self.send_response(code)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Connection", "close")
        self.end_headers()
        self.wfile.write(body)
        self.close_connection = True

    def hold(self, hold_s):
        """Leave the request unanswered until the client closes the connection or hold_s passes."""
        self.close_connection = True
        self.connection.settimeout(0.2)
        deadline = time.monotonic() + hold_s
        while time.monotonic() < deadline and not self.server.device.stop.is_set():
            try:
                if not self.connection.recv(4096):
                    return
            except socket.timeout:
                continue
            except OSError:
                return


class AtiHttp:
    """Net F/T configuration plane: GET /netftapi2.xml."""

    def __init__(self, load, faults, stop, rate_hz=1000.0):
        self.load, self.faults, self.stop, self.rate_hz = load, faults, stop, rate_hz
        self.server = ThreadingHTTPServer((HOST, 0), _NetFtHandler)
        self.server.daemon_threads = True
        self.server.device = self
        self.port = self.server.server_address[1]

    def serve(self):
        self.server.serve_forever(poll_interval=0.2)

    def document(self, fx):
        fu, sfu, tu, stu, calsn, cpf, cpt = 2, "N", 3, "Nm", "FT12345", CPF, CPT
        if f := fx.take("force_unit"):
            fu, sfu = int(f.get("code", 1)), str(f.get("label", "lbf"))
        if f := fx.take("torque_unit"):
            tu, stu = int(f.get("code", 4)), str(f.get("label", "Nmm"))
        if f := fx.take("calibration_changed"):
            calsn, cpf, cpt = str(f.get("calsn", "FT54321")), f.get("cpf", 2_000_000), f.get("cpt", cpt)
        number = lambda v: str(int(v)) if float(v).is_integer() else repr(float(v))
        joined = lambda values: ";".join(str(v) for v in values)
        fields = [
            ("prodname", "Net F/T"), ("runstat", "0x00000000"), ("runrate", 7000),
            ("runft", joined(to_counts(self.load.net())[0])), ("setcfgsel", 0), ("cfgnam", "egcal"),
            ("cfgcalsel", 0), ("cfgcalsn", calsn), ("cfgfu", fu), ("scfgfu", sfu), ("cfgtu", tu),
            ("scfgtu", stu), ("cfgcpf", number(cpf)), ("cfgcpt", number(cpt)), ("cfgtfx", "0;0;0;0;0;0"),
            ("scfgtdu", "mm"), ("scfgtau", "degrees"), ("cfgmr", "2500;2500;6250;400;400;400"),
            ("setbias", joined(to_counts(self.load.get_bias())[0])), ("setuserfilter", 0),
            ("comrdte", "Enabled"), ("comrdtrate", number(self.rate_hz)), ("comrdtbsiz", 1),
            ("nethwaddr", "00:16:BD:00:23:56"), ("netip", HOST), ("mfgdigsn", "LOT2821"), ("mfgdigver", "2.2.59"),
        ]
        xml = "".join(f"<{name}>{escape(str(value))}</{name}>" for name, value in fields)
        return f'<?xml version="1.0"?><netft>{xml}</netft>'.encode()


class CableRobot:
    """egcal cable-robot controller (schemas/cable-robot-udp.md), four cables."""

    MAGIC, VERSION = 0x45434450, 1
    REQUEST = struct.Struct(">IHHI6dI")  # 64 bytes
    REPLY = struct.Struct(">IHHIII6dHH8d")  # 136 bytes
    SET_WRENCH, RELEASE, STATUS = 1, 2, 3
    COMMANDS = {1: "SET_WRENCH", 2: "RELEASE", 3: "STATUS"}
    IDLE, RAMPING, HOLDING, FAULT = 0, 1, 2, 3
    STATES = ("IDLE", "RAMPING", "HOLDING", "FAULT")
    FLAG_UPPER_TENSION, FLAG_INFEASIBLE, FLAG_ESTOP = 1 << 1, 1 << 2, 1 << 3
    MAX_FORCE_N, MAX_MOMENT_NM, PRETENSION_N = 2000.0, 300.0, 100.0
    CABLE_DIRS = [(math.cos(math.radians(a)), math.sin(math.radians(a))) for a in (45, 135, 225, 315)]

    def __init__(self, load, faults, stop, backend=None):
        self.load, self.faults, self.stop, self.backend = load, faults, stop, backend
        self.sock = udp_socket()
        self.port = self.sock.getsockname()[1]
        self.state, self.target, self.ramp_left = self.IDLE, [0.0] * 6, 0
        self.releasing = self.infeasible = False

    def serve(self):
        udp_serve(self.sock, self.stop, self.handle)

    def handle(self, data, addr):
        fields = self.REQUEST.unpack(data) if len(data) == self.REQUEST.size else None
        if fields is None or fields[0] != self.MAGIC or fields[1] != self.VERSION or fields[2] not in self.COMMANDS:
            log(f"cable_robot: ignored a {len(data)}-byte datagram from {addr[0]}:{addr[1]} {data[:8].hex()}")
            return
        command, seq, wrench = fields[2], fields[3], list(fields[4:10])
        log(f"cable_robot: {self.COMMANDS[command]} seq {seq} wrench {wrench} from {addr[0]}:{addr[1]}")
        fx = self.faults.check("cable_robot")
        if fx.take("die"):
            die("cable_robot")
        if fx.take("no_reply"):
            return
        estop = fx.take("estop")
        if not estop:
            self.execute(command, wrench, fx)
        state, flags = (self.FAULT, self.FLAG_ESTOP) if estop else (self.state, 0)
        if self.infeasible:
            flags |= self.FLAG_INFEASIBLE
        if state == self.HOLDING and fx.take("tension_limit"):
            flags |= self.FLAG_UPPER_TENSION
        applied = self.load.get_applied()
        tensions = self.tensions(applied) + [0.0] * 4
        reply = self.REPLY.pack(self.MAGIC, self.VERSION, command, seq, state, flags, *applied, 4, 0, *tensions)
        if f := fx.take("malformed"):
            variant = f.get("variant", "size")
            if variant == "magic":
                reply = struct.pack(">I", 0x50444345) + reply[4:]
            elif variant == "version":
                reply = reply[:4] + struct.pack(">H", 2) + reply[6:]
            else:
                reply = reply[:100]
        log(f"cable_robot: reply seq {seq} {self.STATES[state]} flags 0x{flags:02x} wrench {applied}")
        if f := fx.take("late_reply"):
            timer = threading.Timer(float(f.get("delay_s", 1.0)), self.send, (reply, addr))
            timer.daemon = True
            timer.start()
        else:
            self.send(reply, addr)

    def send(self, reply, addr):
        try:
            self.sock.sendto(reply, addr)
        except OSError as e:
            log(f"cable_robot: send to {addr[0]}:{addr[1]} failed ({e})")

    def execute(self, command, wrench, fx):
        if command == self.SET_WRENCH:
            if fx.take("infeasible") or not self.feasible(wrench):
                self.infeasible = True  # not applied; the state stays as it was
                return
            if not self.call_backend("apply_wrench", wrench):
                return
            self.target, self.state, self.ramp_left = wrench, self.RAMPING, 2
            self.releasing = self.infeasible = False
        elif command == self.RELEASE:
            if not self.call_backend("release_wrench"):
                return
            self.target, self.state, self.ramp_left = [0.0] * 6, self.RAMPING, 1
            self.releasing, self.infeasible = True, False
        elif self.state == self.RAMPING:  # STATUS advances the ramp
            if fx.take("never_holds"):
                return
            if self.ramp_left > 0:
                self.ramp_left -= 1
            elif self.releasing:
                self.state = self.IDLE
                self.load.set_applied([0.0] * 6)
            else:
                self.state = self.HOLDING
                self.load.set_applied(self.target)

    def call_backend(self, method, *args):
        """Forwards a command to the backend: False (and the refusal or FAULT set) when it fails."""
        if self.backend is None:
            return True
        try:
            getattr(self.backend, method)(*args)
            return True
        except BackendError as e:
            if "infeasible" in str(e).lower():
                log(f"cable_robot: backend {method} refused the set-point as infeasible: {e}")
                self.infeasible = True
            else:
                log(f"cable_robot: backend {method} failed: {e}; state FAULT")
                self.state, self.infeasible = self.FAULT, False
            return False

    def feasible(self, w):
        return (all(math.isfinite(v) for v in w)
                and math.hypot(*w[:3]) <= self.MAX_FORCE_N and math.hypot(*w[3:]) <= self.MAX_MOMENT_NM)

    def tensions(self, w):
        force, moment = math.hypot(*w[:3]), math.hypot(*w[3:])
        return [self.PRETENSION_N + 0.5 * force + 0.25 * (w[0] * cx + w[1] * cy) + moment
                for cx, cy in self.CABLE_DIRS]


def write_ready(path, ports):
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(ports, f)
        f.write("\n")
    os.replace(tmp, path)


def main(argv=None):
    parser = argparse.ArgumentParser(description="ATI Net F/T + cable-robot + ABB RWS + Leica emScon emulator for tests")
    parser.add_argument("--ready-file", required=True, help="where to write the ports (JSON) once bound")
    parser.add_argument("--faults", help="JSON fault file, re-read before each request")
    parser.add_argument("--seed", type=int, default=0, help="seed of the +-2-count force noise")
    parser.add_argument("--joint-limits", metavar="JSON",
                        help="the controller's joint limits, six [min, max] pairs in degrees (default +-180)")
    parser.add_argument("--rws-version", type=int, choices=(1, 2), default=1,
                        help="Robot Web Services 1.0 (HTTP, Digest) or 2.0 (HTTPS, Basic)")
    parser.add_argument("--rdt-rate", type=float, default=1000.0,
                        help="the Net F/T's RDT output rate (comrdtrate), Hz")
    parser.add_argument("--reflectors-answer", choices=EmsconEmulator.REFLECTORS_ANSWERS, default="records",
                        help="how the tracker answers GetReflectors")
    parser.add_argument("--sim-driver", metavar="JSON",
                        help='command of a driver-protocol simulator as a JSON list, e.g. ["egcal", "sim-driver", ...]')
    args = parser.parse_args(argv)
    if not (math.isfinite(args.rdt_rate) and args.rdt_rate > 0):
        parser.error("--rdt-rate: expected a positive rate in Hz")
    command = None
    if args.sim_driver is not None:
        try:
            command = json.loads(args.sim_driver)
        except ValueError as e:
            parser.error(f"--sim-driver: not JSON ({e})")
        if not (isinstance(command, list) and command and all(isinstance(c, str) for c in command)):
            parser.error("--sim-driver: expected a non-empty JSON list of strings")

    stop = threading.Event()
    backend = None
    if command is not None:
        try:
            backend = SimBackend(command)
        except BackendError as e:
            log(f"cannot start the simulator {json.dumps(command)}: {e}")
            return 2
        log(f"simulator {json.dumps(command)} ready ({backend.name})")
    load, faults = Load(), Faults(args.faults)
    ati_http = AtiHttp(load, faults, stop, args.rdt_rate)
    ati_rdt = AtiRdt(load, faults, args.seed, stop, backend, args.rdt_rate)
    robot = CableRobot(load, faults, stop, backend)
    try:
        rws = RwsEmulator(args.rws_version, faults, backend, log=log,
                          joint_limits=json.loads(args.joint_limits) if args.joint_limits else None)
    except (OSError, subprocess.CalledProcessError, ssl.SSLError) as e:
        log(f"cannot start the RWS {args.rws_version}.0 server: {e}")
        if backend is not None:
            backend.shutdown()
        return 2
    try:
        tracker = EmsconEmulator(faults, backend, log=log, reflectors_answer=args.reflectors_answer)
    except OSError as e:
        log(f"cannot start the emScon tracker server: {e}")
        rws.close()
        if backend is not None:
            backend.shutdown()
        return 2
    threads = [threading.Thread(target=t, daemon=True)
               for t in (ati_http.serve, ati_rdt.serve, ati_rdt.stream_loop, robot.serve)]
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda signum, frame: stop.set())
    for t in threads:
        t.start()
    rws.start()
    tracker.start()
    ports = {"ati_http": ati_http.port, "ati_rdt": ati_rdt.port, "cable_robot": robot.port,
             "rws": rws.port, "rws_version": args.rws_version, "tracker": tracker.port, "pid": os.getpid()}
    write_ready(args.ready_file, ports)
    log(f"ready {json.dumps(ports)}")
    while not stop.is_set():
        time.sleep(0.1)
    log("signal received, stopping")
    ati_http.server.shutdown()
    ati_http.server.server_close()
    for t in threads:
        t.join(timeout=2.0)
    ati_rdt.sock.close()
    robot.sock.close()
    rws.close()
    tracker.close()
    if backend is not None:
        backend.shutdown()
    log("stopped")
    return 0


if __name__ == "__main__":
    sys.exit(main())
