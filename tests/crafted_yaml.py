"""Hostile YAML documents for the loaders' bounds (sequence files)."""

# A billion laughs: nine levels of ten aliases each over ten "lol"s expand to 10**9 strings from 1 KB.
BILLION_LAUGHS = "a: &a [lol,lol,lol,lol,lol,lol,lol,lol,lol,lol]\n" + "".join(
    f"{name}: &{name} [{', '.join([f'*{previous}'] * 10)}]\n" for previous, name in zip("abcdefgh", "bcdefghi"))

# An alias inside the node it names: a list that contains itself.
SELF_REFERENCE = "name: &loop [*loop]\nchannels: [front]\nsteps: *loop\n"
