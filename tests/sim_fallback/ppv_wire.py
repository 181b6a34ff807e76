"""The host's side of a Peta-pico-Voltron exchange, as its reference library does it."""


def ppv_exchange(link, line: str) -> str:
    """Write ``line`` + CR, read one line, drop its CR LF (``link``: a pyserial or in-memory port)."""
    link.write(line.encode() + b"\r")
    answer = link.readline()
    assert answer.endswith(b"\r\n"), answer
    return answer[:-2].decode()
