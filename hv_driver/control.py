"""Who may command the outputs: one client at a time holds control, proven by a random session token.

Pure logic, time passed in. A client claims control under its name and gets a fresh token; ramps and
heartbeats must carry that token. Control ends when the client releases it, when its heartbeat stops for
longer than the timeout (it lapses), or at an e-stop. A token from an earlier session (a recording played
back, a restarted client) is never the live one, so it can neither feed the watchdog nor ramp.

The silence counts the time the driver could hear the client. While the driver's own process stalls, the
client's heartbeats wait in the transport's buffers (or the client stalled with it, on a shared host), so the
first check after the stall would find them all missing. A gap between two control cycles (`cycle`) counts
towards the silence by at most LOOP_STALL_FRACTION of the timeout: a loop that keeps its period counts every
second of it, and a dead client still lapses, later by at most its driver's own stalls.
"""
import hmac
import math
import secrets

from .errors import HvError, SettingError

MAX_CLIENT_NAME = 64  # [characters] names appear in refusals and /diagnostics
TOKEN_BYTES = 16
# A new session's first sign of life follows the claim's reply across the network; on a lossy link a lost reply
# is resent only at the transport's next periodic heartbeat (Fast DDS: every 3 s), so the client may learn its
# token seconds after the claim. Until it shows it, nothing is energised under the session (every ramp carries
# the token), so the longer wait costs only the time another client waits to claim.
FIRST_SIGN_OF_LIFE_S = 10.0
# The most of the client's allowed silence one gap between the driver's control cycles may use up. A loop that
# cycles slower than that (every 0.5 s for a 2 s timeout) is stalled: descheduled, or waiting on a supply that
# does not answer (which the link watchdog trips on).
LOOP_STALL_FRACTION = 0.25


class ControlError(HvError, RuntimeError):
    """A command from a client that does not hold control; the message names the current owner."""


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
        self._last_heartbeat = -math.inf
        self._confirmed = False  # the owner has shown its token since the claim
        self._last_cycle: float | None = None  # the driver's last control cycle (None before its first)
        self._unheard = 0.0  # [s] of the current silence the driver's loop was stalled (not counted)
        self.ended = ""  # why the last control session ended, e.g. "control released by 'demo'"

    def heartbeat_age(self, now: float) -> float | None:
        """Seconds since the owner's last sign of life (None without an owner)."""
        return None if self.owner is None else max(0.0, now - self._last_heartbeat)

    @property
    def allowed_silence_s(self) -> float:
        """How long the owner may stay silent: the timeout, or FIRST_SIGN_OF_LIFE_S if longer until its first sign."""
        return self.timeout_s if self._confirmed else max(self.timeout_s, FIRST_SIGN_OF_LIFE_S)

    @property
    def _max_cycle_gap_s(self) -> float:
        return LOOP_STALL_FRACTION * self.timeout_s

    def _stalled_since_cycle(self, now: float) -> float:
        """How much of the time since the last control cycle (and since the last heartbeat) is a stall [s]."""
        if self._last_cycle is None:
            return 0.0
        return max(0.0, now - max(self._last_cycle + self._max_cycle_gap_s, self._last_heartbeat))

    def cycle(self, now: float) -> None:
        """The driver's control loop ran a cycle at ``now``; a gap since its previous one is a stall of the driver
        (its time beyond the most a gap may count is not the client's silence)."""
        if self._last_cycle is not None and now < self._last_cycle:
            return
        self._unheard += self._stalled_since_cycle(now)
        self._last_cycle = now

    def silence(self, now: float) -> float:
        """Seconds the owner has been silent while the driver could hear it (0 without an owner)."""
        if self.owner is None:
            return 0.0
        return max(0.0, now - self._last_heartbeat - self._unheard - self._stalled_since_cycle(now))

    def silent(self, now: float) -> bool:
        """True when the owner has been silent for longer than it may be."""
        return self.owner is not None and self.silence(now) > self.allowed_silence_s

    def _heard(self, now: float) -> None:
        self._last_heartbeat, self._unheard = now, 0.0

    def claim(self, client: str, now: float) -> str:
        """Take control as ``client``; returns the session token. Refused while another session is live.

        A claim repeated under the owner's name before the session's first sign of life is answered with the
        same token: the client may never have received the first reply (one written before the DDS discovery
        between the two had finished is lost for good), and nothing has been commanded under it yet."""
        client = _valid_client_name(client)
        self.lapse_if_silent(now)
        if self.owner == client and not self._confirmed:
            self._heard(now)
            return self._token
        if self.owner is not None:
            raise ControlError(f"control is held by {self.owner!r} (last heartbeat {self.heartbeat_age(now):.1f} s "
                               f"ago); it must release it first{self._lapse_hint()}")
        self.owner, self._token = client, self._new_token()
        self._heard(now)
        self._confirmed = False
        self.ended = ""
        return self._token

    def _lapse_hint(self) -> str:
        return "" if math.isinf(self.timeout_s) else f" or stay silent for {self.allowed_silence_s:g} s"

    def confirm(self, token, now: float) -> None:
        """A command carrying ``token``: accepted as the owner's sign of life, else ControlError naming the owner."""
        self.lapse_if_silent(now)
        if not self._is_live(token):
            raise ControlError(self._refusal())
        if now >= self._last_heartbeat:
            self._heard(now)
        self._confirmed = True

    def release(self, token, now: float) -> str:
        """End the session of ``token``; returns the name of the client that released."""
        self.lapse_if_silent(now)
        if not self._is_live(token):
            raise ControlError(self._refusal())
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

    def _is_live(self, token) -> bool:
        return (self._token is not None and isinstance(token, str) and token.isascii()
                and hmac.compare_digest(token, self._token))

    def _refusal(self) -> str:
        if self.owner is not None:
            return f"refused: control is held by {self.owner!r}, and this token is not its session's"
        ended = f" ({self.ended})" if self.ended else ""
        return f"refused: no client holds control{ended}; claim it first"
