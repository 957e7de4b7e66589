"""The password policy (NIST SP 800-63B style: length and a block list rather than composition rules),
applied when an account is created and when a password is changed:

- at least MIN_LENGTH (10) characters;
- not only whitespace, and at least 4 different characters ("aaaaaaaaaa", "1212121212");
- not a common password (common_passwords.txt, a few thousand entries), looked up lower-cased, without
  the digits and symbols around it and with leetspeak undone ("P@ssw0rd2024!" is "password");
- not containing the name part of the account's e-mail address, nor a word (4+ characters) of it.

`check(password, email)` raises WeakPassword naming the rule; its message is shown to the user."""

from __future__ import annotations

import re
from functools import lru_cache
from pathlib import Path

MIN_LENGTH = 10
MIN_DISTINCT = 4
LIST_FILE = Path(__file__).with_name("common_passwords.txt")
_LEET = str.maketrans({"@": "a", "4": "a", "0": "o", "1": "i", "!": "i", "3": "e", "$": "s", "5": "s",
                       "7": "t", "+": "t", "8": "b", "9": "g", "|": "l"})
_EDGES = re.compile(r"^[\W\d_]+|[\W\d_]+$")
_NON_ALNUM = re.compile(r"[\W_]+")


class WeakPassword(ValueError):
    def __init__(self, rule: str, message: str):
        super().__init__(message)
        self.rule = rule


@lru_cache(maxsize=1)
def common_passwords() -> frozenset[str]:
    words = set()
    for line in LIST_FILE.read_text(encoding="utf-8").splitlines():
        line = line.strip().lower()
        if line and not line.startswith("#"):
            words.add(line)
    return frozenset(words)


def _candidates(password: str) -> set[str]:
    """The forms of a password looked up in the list."""
    low = password.lower().strip()
    forms = {low, _NON_ALNUM.sub("", low)}
    core = _EDGES.sub("", low)
    forms |= {core, _NON_ALNUM.sub("", core)}
    for f in list(forms):
        t = f.translate(_LEET)
        forms |= {t, t.replace("i", "l"), _EDGES.sub("", t), _NON_ALNUM.sub("", t)}
        # "1" read as "l" as well as "i"
        forms.add(f.replace("1", "l").translate(_LEET))
    return {f for f in forms if f}


def is_common(password: str) -> bool:
    words = common_passwords()
    return any(f in words for f in _candidates(password))


def check(password: str, email: str | None = None) -> None:
    if not isinstance(password, str) or len(password) < MIN_LENGTH:
        raise WeakPassword("min_length", f"password: must have at least {MIN_LENGTH} characters")
    if not password.strip():
        raise WeakPassword("whitespace", "password: must not be only spaces")
    if len(set(password)) < MIN_DISTINCT:
        raise WeakPassword("repetitive", f"password: too repetitive (use at least {MIN_DISTINCT} different "
                                         "characters)")
    if is_common(password):
        raise WeakPassword("common", "password: too common (it is on the list of the most used passwords, "
                                     "give or take digits and symbols)")
    if _contains_email_name(password, email):
        raise WeakPassword("contains_email", "password: must not contain the name part of the e-mail address "
                                             "(nor a word of it)")


def _contains_email_name(password: str, email: str | None) -> bool:
    """The e-mail's name part (3+ characters), with or without its separators, or one of its words of
    4+ characters ("jane.doe": "jane.doe", "janedoe", "jane") found in the password, case ignored."""
    local = (email or "").strip().lower().rsplit("@", 1)[0]
    if len(local) < 3:
        return False
    low = password.lower()
    compact_pw = _NON_ALNUM.sub("", low)
    compact_local = _NON_ALNUM.sub("", local)
    if local in low or (len(compact_local) >= 3 and compact_local in compact_pw):
        return True
    return any(len(w) >= 4 and w in low for w in _NON_ALNUM.split(local))
