"""Who may command the outputs: one client at a time holds control, proven by commands signed with a session token.

Pure logic, time passed in. A client claims control under its name and gets a fresh token, the session's secret:
it travels once, in the claim's reply, and never again. What the client sends afterwards (heartbeats, ramps,
pulse trains, the release) carries the session's public id, a counter it raises with every message and an
HMAC-SHA256 of (session id, counter, the command's content) keyed with the token (`SessionKey.sign`, `signed`).
The driver accepts each counter once: a copied or replayed message (a recording played back, a subscriber that
re-sends what it saw) repeats a counter and is refused, and it cannot be turned into another command because the
signature covers the content. Counters may arrive out of order across topics and services (a heartbeat overtaking
a ramp goal), so the newest REPLAY_WINDOW counters are tracked one by one, as in IPsec's anti-replay window (RFC
4303, 3.4.3); an older one is refused. A caller in the driver's own process may pass the token itself.

Control ends when the client releases it, when its heartbeat stops for longer than the timeout (it lapses), or at
an e-stop. A token from an earlier session (a restarted client) is never the live one, so its commands can
neither feed the watchdog nor ramp. This guards against accidents, not an attacker in the DDS domain: without
DDS-Security anyone there can read the claim's reply too (docs/hv_driver.md, "Who may command").

The silence is the time since the owner's last sign of life was sent. A caller that hears the client through a
channel (the supervisor process, `hv_driver.server`) passes each heartbeat's sending time (``sent``: the node's
CLOCK_MONOTONIC stamp, comparable between processes on one host) and takes in what waits in that channel before the
silence is judged, so a stall of the driver's own process neither ends a live client's session (its beats are read,
with their stamps, before the judgement) nor delays the lapse of a dead one.
"""
import hashlib
import hmac
import json
import math
import re
import secrets
import threading

from .errors import HvError, SettingError

MAX_CLIENT_NAME = 64  # [characters] names appear in refusals and /diagnostics
TOKEN_BYTES = 16
MAX_NONCE = 64  # [characters] a claim's nonce, chosen by the client
REPLAY_WINDOW = 64  # counters below the newest accepted one by this many or more are refused
MAX_COUNTER = 2**63 - 1
_MAC = re.compile(r"[0-9a-f]{64}")
_SIGNED = re.compile(r"(?P<session>[0-9a-f]{16}):(?P<counter>[0-9]{1,19}):(?P<mac>[^:]*)")
HEARTBEAT = ("heartbeat",)  # the content of a heartbeat
RELEASE = ("release",)  # the content of hv/release_control
# A new session's first sign of life follows the claim's reply across the network; on a lossy link a lost reply
# is resent only at the transport's next periodic heartbeat (Fast DDS: every 3 s), so the client may learn its
# token seconds after the claim. Until it shows it, nothing is energised under the session (every ramp carries
# the token), so the longer wait costs only the time another client waits to claim.
FIRST_SIGN_OF_LIFE_S = 10.0


class ControlError(HvError, RuntimeError):
    """A command from a client that does not hold control; the message names the current owner."""


def session_id(token: str) -> str:
    """The public name of the session of ``token``: a hash that does not reveal it."""
    return hashlib.sha256(b"softblock session id\0" + token.encode()).hexdigest()[:16]


def ramp_command(channel: str, target_v: float, slew_rate_v_per_s: float | None) -> tuple:
    """The signed content of a ramp (slew rate None or 0: the configured one)."""
    return "ramp", channel, float(target_v), float(slew_rate_v_per_s or 0.0)


def pulse_command(channels: list[str], amplitude_v: float, frequency_hz: float, duty: float, phase: float,
                  cycles: int, edge: str, slew_rate_v_per_s: float | None) -> tuple:
    """The signed content of a pulse train (slew rate None or 0: the configured one)."""
    return ("pulse", list(channels), float(amplitude_v), float(frequency_hz), float(duty), float(phase), int(cycles),
            edge, float(slew_rate_v_per_s or 0.0))


def command_mac(token: str, session: str, counter: int, command) -> str:
    """HMAC-SHA256 keyed with the session token over (session id, counter, command content), in hex."""
    message = json.dumps([session, counter, list(command)], separators=(",", ":")).encode()
    return hmac.new(token.encode(), message, hashlib.sha256).hexdigest()


def signed(session: str, counter: int, mac: str) -> str:
    """The credential of one signed command, as a node passes on the fields of a message."""
    return f"{session}:{counter}:{mac}"


class SessionKey:
    """The client's side of a session: signs each message with the next counter (thread-safe)."""

    def __init__(self, token: str):
        self.session = session_id(token)
        self._token, self._counter, self._lock = token, 0, threading.Lock()

    def sign(self, command) -> tuple[str, int, str]:
        """(session id, counter, mac) of ``command`` (e.g. HEARTBEAT, `ramp_command(...)`)."""
        with self._lock:
            self._counter += 1
            counter = self._counter
        return self.session, counter, command_mac(self._token, self.session, counter, command)


def _valid_client_name(client) -> str:
    if not (isinstance(client, str) and client.strip() and client.isprintable() and len(client) <= MAX_CLIENT_NAME):
        raise SettingError(f"client={client!r}: a printable name of 1 to {MAX_CLIENT_NAME} characters")
    return client


class ControlClaim:
    """The controlling client of one supply.

    timeout_s: seconds without a heartbeat after which control lapses (math.inf: never lapses; then only a
        release or an e-stop ends it).
    new_token: source of session tokens (default: 128 random bits from `secrets`).
    """

    def __init__(self, timeout_s: float, new_token=lambda: secrets.token_hex(TOKEN_BYTES)):
        self.timeout_s = timeout_s
        self._new_token = new_token
        self.owner: str | None = None
        self._token: str | None = None
        self._session = ""
        self._nonce = ""  # the claim's nonce: only the same claim, repeated, gets the same session again
        self._newest = 0  # the newest counter accepted in this session
        self._recent: set[int] = set()  # counters accepted within REPLAY_WINDOW of the newest
        self._last_heartbeat = -math.inf
        self._confirmed = False  # the owner has shown its token since the claim
        self.ended = ""  # why the last control session ended, e.g. "control released by 'demo'"

    def heartbeat_age(self, now: float) -> float | None:
        """Seconds since the owner's last sign of life (None without an owner)."""
        return None if self.owner is None else max(0.0, now - self._last_heartbeat)

    @property
    def allowed_silence_s(self) -> float:
        """How long the owner may stay silent: the timeout, or FIRST_SIGN_OF_LIFE_S if longer until its first sign."""
        return self.timeout_s if self._confirmed else max(self.timeout_s, FIRST_SIGN_OF_LIFE_S)

    def silence(self, now: float) -> float:
        """Seconds since the owner's last sign of life (0 without an owner)."""
        if self.owner is None:
            return 0.0
        return max(0.0, now - self._last_heartbeat)

    def silent(self, now: float) -> bool:
        """True when the owner has been silent for longer than it may be."""
        return self.owner is not None and self.silence(now) > self.allowed_silence_s

    def _heard(self, now: float) -> None:
        self._last_heartbeat = now

    def claim(self, client: str, now: float, nonce: str = "") -> str:
        """Take control as ``client``; returns the session token. Refused while another session is live.

        A claim repeated with the same client name and (non-empty) ``nonce`` before the session's first sign of
        life is answered with the same token: the client may never have received the first reply (one written
        before the DDS discovery between the two had finished is lost for good), and nothing has been commanded
        under it yet. Any other claim, also one of another client racing under the same name, is refused."""
        client = _valid_client_name(client)
        if not (isinstance(nonce, str) and len(nonce) <= MAX_NONCE and nonce.isprintable()):
            raise SettingError(f"nonce={nonce!r}: printable, at most {MAX_NONCE} characters")
        self.lapse_if_silent(now)
        if self.owner == client and not self._confirmed and nonce and hmac.compare_digest(nonce, self._nonce):
            self._heard(now)
            return self._token
        if self.owner is not None:
            raise ControlError(f"control is held by {self.owner!r} (last heartbeat {self.heartbeat_age(now):.1f} s "
                               f"ago); it must release it first{self._lapse_hint()}")
        self.owner, self._token, self._nonce = client, self._new_token(), nonce
        self._session, self._newest, self._recent = session_id(self._token), 0, set()
        self._heard(now)
        self._confirmed = False
        self.ended = ""
        return self._token

    @property
    def session(self) -> str:
        """The live session's public id ("" without an owner)."""
        return self._session if self.owner is not None else ""

    def _lapse_hint(self) -> str:
        return "" if math.isinf(self.timeout_s) else f" or stay silent for {self.allowed_silence_s:g} s"

    def confirm(self, credential, now: float, command=HEARTBEAT, sent: float | None = None) -> None:
        """A command with ``credential`` (a `signed` command of content ``command``, or the token itself): accepted
        as the owner's sign of life, else ControlError naming the owner and why. ``sent``: when the client's
        channel took it (at most ``now``): it counts from then, if the session was still live then."""
        at = now if sent is None else min(sent, now)
        self.lapse_if_silent(at)
        self._authenticate(credential, command)
        if at >= self._last_heartbeat:
            self._heard(at)
        self._confirmed = True

    def release(self, credential, now: float) -> str:
        """End the session of ``credential`` (signed RELEASE, or the token); returns the client that released."""
        self.lapse_if_silent(now)
        self._authenticate(credential, RELEASE)
        owner = self.owner
        self.end(f"control released by {owner!r}")
        return owner

    def lapse_if_silent(self, now: float) -> str | None:
        """End a session whose heartbeat stopped; returns the lapsed owner's name."""
        if not self.silent(now):
            return None
        owner, allowed = self.owner, self.allowed_silence_s
        self.end(f"control of {owner!r} lapsed: no heartbeat for more than {allowed:g} s")
        return owner

    def end(self, reason: str) -> None:
        if self.owner is not None:
            self.ended = reason
        self.owner = self._token = None

    def _authenticate(self, credential, command) -> None:
        """Raise ControlError unless ``credential`` proves the live session for ``command`` (a counter once)."""
        if self._token is None or not (isinstance(credential, str) and credential.isascii()):
            raise ControlError(self._refusal("this command is not its session's"))
        if hmac.compare_digest(credential, self._token):
            return
        fields = _SIGNED.fullmatch(credential)
        if fields is None:
            raise ControlError(self._refusal("this command is not its session's"))
        if fields["session"] != self._session:
            raise ControlError(self._refusal(f"this command is for session {fields['session']}, not its session "
                                             f"{self._session}"))
        counter = int(fields["counter"])
        expected = command_mac(self._token, self._session, counter, command)
        if not (_MAC.fullmatch(fields["mac"]) and hmac.compare_digest(fields["mac"], expected)):
            raise ControlError(self._refusal("this command's signature does not match its session's"))
        if not 0 < counter <= MAX_COUNTER or counter <= self._newest - REPLAY_WINDOW or counter in self._recent:
            raise ControlError(self._refusal(f"counter {counter} was used already or is too old (newest "
                                             f"{self._newest}): a copied or replayed command"))
        self._newest = max(self._newest, counter)
        self._recent = {c for c in self._recent if c > self._newest - REPLAY_WINDOW} | {counter}

    def _refusal(self, why: str) -> str:
        if self.owner is not None:
            return f"refused: control is held by {self.owner!r}, and {why}"
        ended = f" ({self.ended})" if self.ended else ""
        return f"refused: no client holds control{ended}; claim it first"
