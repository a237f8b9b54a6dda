#!/usr/bin/env python3
"""Leica laser-tracker emulator (emScon TPI over TCP) for egcal's lab-driver tests (Python 3.11, standard library only).

EmsconEmulator(faults=..., backend=..., reflectors_answer=...) serves the emScon Tracker Programming
Interface on 127.0.0.1 (port 0 = ephemeral; see .port) in its own threads, as in notes/i18-protocols.md
section 3. Layouts, command numbers and statuses are those of Leica's TPI header ES_C_API_Def.h
(emScon TPI/SDK 3.6).

Wire format: binary C structs, little-endian, #pragma pack(4), `long` = i32. Every packet starts with
PacketHeaderT {i32 lPacketSize (whole packet), i32 type}; packets are split by lPacketSize.
  BasicCommandCT   12  {size, type 0, command}                 (+ parameters, see COMMAND_SIZES)
  BasicCommandRT   16  {16, 0, command, status}                every command but GetReflectors gets one
  ErrorResponseT   16  {16, 1, command, status}
  GetReflectorsRT 100  BasicCommandRT {100, 0, 42, status} + int iTotalReflectors, int iInternalReflectorId,
                       enum targetType, f64 dSurfaceOffset (offset 28), unsigned short cReflectorName[32]
                       (UTF-16LE, NUL-padded, offset 36): the answer to GetReflectors, one per reflector
  SingleMeasResultT 156 {156, 2, status, measMode, bIsTryMode, 17 f64: dVal1..3, dStd1..3, dStdTotal,
                       dPointingError1..3, dAprioriStd1..3, dAprioriStdTotal, dTemperature, dPressure, dHumidity}

One client at a time: a connection made while another is open gets ErrorResponseT {command 64
(ES_C_Unknown), status 10011 MultiConnectionsNotAllowed} and is closed. A packet whose lPacketSize
is below 12 or above 4096 closes the connection; a packet of another type than 0 is ignored.

Commands (anything else: BasicCommandRT status 2 NotImplemented; a known command whose packet has the
wrong size: status 3 WrongParameter):
  SetUnits 5 (32 bytes)        lenUnit must be 1 (mm) else 4; angUnit 0..2 else 5; tempUnit 0..1 else 6;
                               pressUnit 0..6 else 7; humUnit 0 else 8
  Initialize 7 (12)            the tracker is initialised (at once)
  SetEnvironmentParams 20 (36) temperature, pressure, humidity (finite, else 4/5/6); the results report them
                               (default 20.0 C, 1013.25 mbar, 50.0 %RH)
  SetMeasurementMode 24 (16)   only 0 (stationary), else 4
  SetStationaryModeParams 28 (20) lMeasTime ms > 0 else 4, bUseADM 0/1 else 5 (stored; no wait)
  SetReflector 40 (16)         id 1 or 2, else 4 (the current reflector is 1 until set)
  GetReflectors 42 (12)        one GetReflectorsRT per reflector and nothing else, as the header has it:
                               id 1 "RRR 1.5in" type 5 (ES_TT_RRR15, offset 19.05 mm), id 2 "RRR 0.5in"
                               type 6 (ES_TT_RRR05, offset 6.35 mm). reflectors_answer="status_first"
                               sends a BasicCommandRT {42, 0} before the records, "records_first" after
                               them (servers seen to do either).
  GoBirdBath 54, StopMeasurement 52 (12)  status 0 (GoBirdBath: 39 before Initialize)
  StartMeasurement 49 (12)     before Initialize: RT status 39 and no result. Else RT {49, 0}, then a
                               SingleMeasResultT (status 0, measMode 0, bIsTryMode 0) at backend.measure()
                               ["position_mm"] (or [1000, 200, 800] mm without a backend), std
                               backend sigma_mm or (0.005, 0.005, 0.010) mm, dStdTotal their norm,
                               pointing errors 0, apriori std 0.01 (total: norm of the three).
                               A backend error: RT {49, 0}, then ErrorResponseT {49, 10009}.

Faults (device "tracker" of the fault file, see cell_emulator.py; every kind affects only
StartMeasurement commands, and `times` counts the StartMeasurement commands it affects):
  die                    os._exit(3) as soon as the command arrives
  no_reply               no RT and no result
  late_reply  delay_s    RT and result after delay_s (default 1.0) seconds
  not_warmed_up          RT status 10012 SensorNotWarmedUp, no result
  beam_lost              RT {49, 0}, then ErrorResponseT {16, 1, 49, 10009 NoStationaryResult} instead of a result
  beam_lost_zeros        a result with status 0 and dVal1..3 = 0.0 (a disguised beam loss)
  beam_lost_nan          a result with status 0 and dVal1..3 = NaN
  malformed              RT, then a result whose lPacketSize says 156 but only its first 100 bytes are sent;
                         the connection is then closed
  wrong_units            the result's lengths (values, std, apriori std) in metres (/1000)
The order of the checks: die, no_reply, late_reply (these three before the state checks), then
not initialised (39, no fault used), not_warmed_up, beam_lost, beam_lost_zeros, beam_lost_nan,
wrong_units, malformed. backend.measure() is called only when the result carries the measured
position (no fault, late_reply, wrong_units, malformed), never for die, no_reply, not_warmed_up, the
beam_lost kinds or a tracker not initialised, so a retry sees the same simulator sequence.
measured_at_us is not sent (SingleMeasResultT has no timestamp).
"""
import math
import os
import socket
import struct
import sys
import threading
import time

HOST = "127.0.0.1"

# ES_DataType
DT_COMMAND, DT_ERROR, DT_SINGLE_MEAS_RESULT = 0, 1, 2
# ES_Command
C_SET_UNITS, C_INITIALIZE, C_SET_ENVIRONMENT_PARAMS = 5, 7, 20
C_SET_MEASUREMENT_MODE, C_SET_STATIONARY_MODE_PARAMS = 24, 28
C_SET_REFLECTOR, C_GET_REFLECTORS, C_START_MEASUREMENT = 40, 42, 49
C_STOP_MEASUREMENT, C_GO_BIRD_BATH, C_UNKNOWN = 52, 54, 64
# ES_ResultStatus
RS_ALL_OK, RS_NOT_IMPLEMENTED, RS_WRONG_PARAMETER = 0, 2, 3
RS_WRONG_PARAMETER1 = 4  # WrongParameterN = 3 + N
RS_TRACKER_NOT_INITIALIZED = 39
RS_NO_STATIONARY_RESULT, RS_MULTI_CONNECTIONS_NOT_ALLOWED, RS_SENSOR_NOT_WARMED_UP = 10009, 10011, 10012

HEADER = struct.Struct("<ii")
BASIC_CT = struct.Struct("<iii")  # 12
BASIC_RT = struct.Struct("<iiii")  # 16 (also ErrorResponseT)
REFLECTOR_RT = struct.Struct("<iiiiiiid64s")  # 100
SINGLE_MEAS = struct.Struct("<iiiii17d")  # 156
assert (BASIC_RT.size, REFLECTOR_RT.size, SINGLE_MEAS.size) == (16, 100, 156)

COMMAND_NAMES = {
    C_SET_UNITS: "SetUnits", C_INITIALIZE: "Initialize", C_SET_ENVIRONMENT_PARAMS: "SetEnvironmentParams",
    C_SET_MEASUREMENT_MODE: "SetMeasurementMode", C_SET_STATIONARY_MODE_PARAMS: "SetStationaryModeParams",
    C_SET_REFLECTOR: "SetReflector", C_GET_REFLECTORS: "GetReflectors", C_START_MEASUREMENT: "StartMeasurement",
    C_STOP_MEASUREMENT: "StopMeasurement", C_GO_BIRD_BATH: "GoBirdBath",
}
COMMAND_SIZES = {
    C_SET_UNITS: 32, C_INITIALIZE: 12, C_SET_ENVIRONMENT_PARAMS: 36, C_SET_MEASUREMENT_MODE: 16,
    C_SET_STATIONARY_MODE_PARAMS: 20, C_SET_REFLECTOR: 16, C_GET_REFLECTORS: 12, C_START_MEASUREMENT: 12,
    C_STOP_MEASUREMENT: 12, C_GO_BIRD_BATH: 12,
}
MAX_PACKET = 4096
REFLECTORS = [  # (id, targetType, dSurfaceOffset mm, name)
    (1, 5, 19.05, "RRR 1.5in"),
    (2, 6, 6.35, "RRR 0.5in"),
]
FIXED_POSITION_MM = [1000.0, 200.0, 800.0]
DEFAULT_STD_MM = [0.005, 0.005, 0.010]
APRIORI_STD_MM = 0.01
MALFORMED_BYTES = 100


def _default_log(message):
    print(f"emscon_emulator: {message}", file=sys.stderr, flush=True)


class _NoFaults:
    def check(self, device):
        return self

    def take(self, kind):
        return None


def basic_rt(command, status):
    return BASIC_RT.pack(16, DT_COMMAND, command, status)


def error_response(command, status):
    return BASIC_RT.pack(16, DT_ERROR, command, status)


def reflector_rt(total, rid, target_type, offset_mm, name):
    raw = name.encode("utf-16-le")[:62]
    return REFLECTOR_RT.pack(100, DT_COMMAND, C_GET_REFLECTORS, RS_ALL_OK, total, rid, target_type, offset_mm,
                             raw.ljust(64, b"\0"))


def single_meas_result(position, std, environment, status=RS_ALL_OK, scale=1.0):
    """SingleMeasResultT; every length is multiplied by `scale` (1/1000 = metres)."""
    std_total = math.sqrt(sum(s * s for s in std))
    apriori = [APRIORI_STD_MM] * 3
    apriori_total = math.sqrt(sum(a * a for a in apriori))
    lengths = [*position, *std, std_total, 0.0, 0.0, 0.0, *apriori, apriori_total]
    return SINGLE_MEAS.pack(SINGLE_MEAS.size, DT_SINGLE_MEAS_RESULT, status, 0, 0,
                            *[v * scale for v in lengths], *environment)


class EmsconEmulator:
    REFLECTORS_ANSWERS = ("records", "status_first", "records_first")

    def __init__(self, faults=None, backend=None, *, log=None, host=HOST, port=0, reflectors_answer="records"):
        if reflectors_answer not in self.REFLECTORS_ANSWERS:
            raise ValueError(f"reflectors_answer {reflectors_answer!r}: expected one of {self.REFLECTORS_ANSWERS}")
        self.reflectors_answer = reflectors_answer
        self.backend = backend
        self.log = log or _default_log
        if isinstance(faults, (str, os.PathLike)):
            sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
            from cell_emulator import Faults
            faults = Faults(os.fspath(faults))
        self.faults = faults if faults is not None else _NoFaults()
        self.lock = threading.Lock()
        self.stop = threading.Event()
        self.client = None  # the socket of the connected client
        # Tracker state (kept across connections, as on the real server).
        self.units = [1, 1, 0, 0, 0]  # mm, degree, Celsius, mbar, RH
        self.environment = [20.0, 1013.25, 50.0]
        self.initialised = False
        self.meas_mode = 0
        self.stationary = (1000, 1)  # lMeasTime ms, bUseADM
        self.reflector = REFLECTORS[0][0]
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind((host, port))
        self.sock.listen(4)
        self.sock.settimeout(0.2)
        self.port = self.sock.getsockname()[1]
        self.thread = None

    # ----------------------------------------------------------------- lifecycle
    def start(self):
        self.thread = threading.Thread(target=self.accept_loop, daemon=True)
        self.thread.start()
        self.log(f"tracker: emScon TPI on tcp://{HOST}:{self.port}")
        return self

    def close(self):
        self.stop.set()
        if self.thread is not None:
            self.thread.join(timeout=2.0)
        with self.lock:
            client = self.client
        if client is not None:
            try:
                client.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
        self.sock.close()

    def accept_loop(self):
        while not self.stop.is_set():
            try:
                conn, addr = self.sock.accept()
            except socket.timeout:
                continue
            except OSError:
                break
            peer = f"{addr[0]}:{addr[1]}"
            with self.lock:
                busy = self.client is not None
                if not busy:
                    self.client = conn
            if busy:
                self.log(f"tracker: refused a second connection from {peer} (status {RS_MULTI_CONNECTIONS_NOT_ALLOWED})")
                try:
                    conn.sendall(error_response(C_UNKNOWN, RS_MULTI_CONNECTIONS_NOT_ALLOWED))
                    conn.shutdown(socket.SHUT_WR)
                except OSError:
                    pass
                conn.close()
                continue
            self.log(f"tracker: client {peer} connected")
            threading.Thread(target=self.serve_client, args=(conn, peer), daemon=True).start()

    # ----------------------------------------------------------------- one client
    def recv_exact(self, conn, n):
        data = b""
        while len(data) < n:
            try:
                chunk = conn.recv(n - len(data))
            except socket.timeout:
                if self.stop.is_set():
                    return None
                continue
            except OSError:
                return None
            if not chunk:
                return None
            data += chunk
        return data

    def serve_client(self, conn, peer):
        conn.settimeout(0.2)
        try:
            while not self.stop.is_set():
                head = self.recv_exact(conn, 4)
                if head is None:
                    break
                (size,) = struct.unpack("<i", head)
                if not BASIC_CT.size <= size <= MAX_PACKET:
                    self.log(f"tracker: lPacketSize {size} from {peer} out of range; closing the connection")
                    break
                rest = self.recv_exact(conn, size - 4)
                if rest is None:
                    break
                if not self.handle(conn, head + rest, peer):
                    break
        except Exception as e:  # a bad fault parameter or a bug: log it, drop this client, keep serving
            self.log(f"tracker: error serving {peer}: {type(e).__name__}: {e}")
        finally:
            with self.lock:  # free the slot first: a client that reconnects on EOF must not get 10011
                if self.client is conn:
                    self.client = None
            try:
                conn.shutdown(socket.SHUT_WR)
            except OSError:
                pass
            conn.close()
            self.log(f"tracker: client {peer} disconnected")

    def handle(self, conn, packet, peer):
        """Answers one packet; False closes the connection."""
        size, ptype, command = BASIC_CT.unpack_from(packet)
        if ptype != DT_COMMAND:
            self.log(f"tracker: ignored a packet of type {ptype} ({size} bytes) from {peer}")
            return True
        name = COMMAND_NAMES.get(command, f"command {command}")
        self.log(f"tracker: {name} ({size} bytes) from {peer}: {packet[12:].hex() or '-'}")
        expected = COMMAND_SIZES.get(command)
        if expected is None:
            return self.send(conn, basic_rt(command, RS_NOT_IMPLEMENTED), f"RT {{{command}, {RS_NOT_IMPLEMENTED}}}")
        if size != expected:
            self.log(f"tracker: {name} should be {expected} bytes, not {size}")
            return self.send(conn, basic_rt(command, RS_WRONG_PARAMETER), f"RT {{{command}, {RS_WRONG_PARAMETER}}}")
        if command == C_START_MEASUREMENT:
            return self.start_measurement(conn)
        if command == C_GET_REFLECTORS:
            return self.get_reflectors(conn)
        status, extra = self.execute(command, packet)
        if not self.send(conn, basic_rt(command, status), f"RT {{{command}, {status}}}"):
            return False
        for reply in extra:
            if not self.send(conn, reply, f"{len(reply)}-byte reply to {name}"):
                return False
        return True

    def send(self, conn, data, what):
        try:
            conn.sendall(data)
        except OSError as e:
            self.log(f"tracker: send of {what} failed ({e})")
            return False
        self.log(f"tracker: sent {what}")
        return True

    def execute(self, command, packet):
        """(status, extra packets after the RT) for every command but StartMeasurement."""
        if command == C_SET_UNITS:
            units = list(struct.unpack_from("<5i", packet, 12))
            limits = [(1, 1), (0, 2), (0, 1), (0, 6), (0, 0)]  # only mm is accepted as length unit
            for i, (value, (lo, hi)) in enumerate(zip(units, limits)):
                if not lo <= value <= hi:
                    return RS_WRONG_PARAMETER1 + i, []
            self.units = units
        elif command == C_INITIALIZE:
            self.initialised = True
        elif command == C_SET_ENVIRONMENT_PARAMS:
            env = list(struct.unpack_from("<3d", packet, 12))
            for i, value in enumerate(env):
                if not math.isfinite(value):
                    return RS_WRONG_PARAMETER1 + i, []
            self.environment = env
        elif command == C_SET_MEASUREMENT_MODE:
            (mode,) = struct.unpack_from("<i", packet, 12)
            if mode != 0:
                return RS_WRONG_PARAMETER1, []
            self.meas_mode = mode
        elif command == C_SET_STATIONARY_MODE_PARAMS:
            meas_time, use_adm = struct.unpack_from("<2i", packet, 12)
            if meas_time <= 0:
                return RS_WRONG_PARAMETER1, []
            if use_adm not in (0, 1):
                return RS_WRONG_PARAMETER1 + 1, []
            self.stationary = (meas_time, use_adm)
        elif command == C_SET_REFLECTOR:
            (rid,) = struct.unpack_from("<i", packet, 12)
            if rid not in {r[0] for r in REFLECTORS}:
                return RS_WRONG_PARAMETER1, []
            self.reflector = rid
        elif command == C_GO_BIRD_BATH:
            if not self.initialised:
                return RS_TRACKER_NOT_INITIALIZED, []
        return RS_ALL_OK, []

    def get_reflectors(self, conn):
        """GetReflectorsRT per reflector; a status-only RT before or after them when so configured."""
        packets = [(reflector_rt(len(REFLECTORS), *r), f"GetReflectorsRT id {r[0]} {r[3]!r}") for r in REFLECTORS]
        status = (basic_rt(C_GET_REFLECTORS, RS_ALL_OK), "RT {42, 0}")
        if self.reflectors_answer == "status_first":
            packets.insert(0, status)
        elif self.reflectors_answer == "records_first":
            packets.append(status)
        return all(self.send(conn, data, what) for data, what in packets)

    def start_measurement(self, conn):
        fx = self.faults.check("tracker")
        if fx.take("die"):
            self.log("tracker: fault die, exiting with status 3")
            os._exit(3)
        if fx.take("no_reply"):
            self.log("tracker: StartMeasurement left unanswered (fault no_reply)")
            return True
        if f := fx.take("late_reply"):
            time.sleep(float(f.get("delay_s", 1.0)))
        rt = lambda status: self.send(conn, basic_rt(C_START_MEASUREMENT, status), f"RT {{49, {status}}}")
        if not self.initialised:
            return rt(RS_TRACKER_NOT_INITIALIZED)
        if fx.take("not_warmed_up"):
            return rt(RS_SENSOR_NOT_WARMED_UP)
        if fx.take("beam_lost"):
            return rt(RS_ALL_OK) and self.send(conn, error_response(C_START_MEASUREMENT, RS_NO_STATIONARY_RESULT),
                                              f"ErrorResponseT {{49, {RS_NO_STATIONARY_RESULT}}} (beam lost)")
        std = list(DEFAULT_STD_MM)
        if fx.take("beam_lost_zeros"):
            position = [0.0, 0.0, 0.0]
        elif fx.take("beam_lost_nan"):
            position = [math.nan] * 3
        elif self.backend is not None:
            try:
                measured = self.backend.measure()
            except Exception as e:  # BackendError, or a backend that broke
                self.log(f"tracker: backend measure failed: {e}")
                return rt(RS_ALL_OK) and self.send(
                    conn, error_response(C_START_MEASUREMENT, RS_NO_STATIONARY_RESULT),
                    f"ErrorResponseT {{49, {RS_NO_STATIONARY_RESULT}}} (backend error)")
            position = list(measured["position_mm"])
            if measured.get("sigma_mm") is not None:
                std = list(measured["sigma_mm"])
        else:
            position = list(FIXED_POSITION_MM)
        scale = 0.001 if fx.take("wrong_units") else 1.0
        result = single_meas_result(position, std, self.environment, scale=scale)
        if not rt(RS_ALL_OK):
            return False
        if fx.take("malformed"):
            self.send(conn, result[:MALFORMED_BYTES],
                      f"{MALFORMED_BYTES} of the 156 bytes of SingleMeasResultT (fault malformed); closing")
            return False
        unit = "m" if scale != 1.0 else "mm"
        return self.send(conn, result, f"SingleMeasResultT {[v * scale for v in position]} {unit}, std {std} mm")


if __name__ == "__main__":  # standalone: python3 emscon_emulator.py [FAULT_FILE]
    emu = EmsconEmulator(sys.argv[1] if len(sys.argv) > 1 else None).start()
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        emu.close()
