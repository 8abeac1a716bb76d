"""The J2735 editions the codec speaks, 2016 and 2020, and what differs between them.

For the project's subset (MessageFrame, BSM, SPaT, MAP, SRM, SSM) the two
editions encode with the same bits wherever both admit a value; they differ in

* TimeMark (SPaT time marks, tenths of a second in the hour): 2016 runs
  0..36001 (36000: more than an hour away, 35991..35999 during a leap second,
  36001 unknown); 2020 runs 0..36111 (36000..36009 the tenths of a leap
  second, 36010..36110 reserved, 36111 unknown). A 2016 "unknown" (36001)
  therefore reads as a leap second to a 2020 receiver, and a 2016 decoder
  refuses a 2020 "unknown" (36111) as out of range: sender and receiver must
  agree on the edition.
* the SSPindex member of EmergencyDetails, PrivilegedEvents and TrailerData:
  `sspRights` in 2016, `notUsed` in 2020 (same position and range; 2020 sends 0
  and gives it no meaning). The typed API (bridges.j2735.bsm) maps the name,
  so user code does not care.

An edition is chosen by name: `edition("2016")`; `edition(None)` is
$V2I_J2735_EDITION, else the newer one. A misspelt name is refused with the
known ones and a "did you mean".
"""
from __future__ import annotations

import difflib
import os
from dataclasses import dataclass

from bridges.j2735.errors import J2735Error

EDITION_ENV = "V2I_J2735_EDITION"
DEFAULT_EDITION = "2020"


@dataclass(frozen=True)
class Edition:
    name: str                     # "2016", "2020"
    time_mark_max: int            # TimeMark ::= INTEGER (0..time_mark_max)
    time_mark_unknown: int        # the code for "undefined or unknown"
    time_mark_last: int           # the largest code that is a time (2016: 36000, 2020: 36009)
    time_mark_reserved: tuple[int, int] | None  # codes the edition reserves (kept as received)
    ssp_member: str               # the SSPindex member's name in EmergencyDetails & co.

    def __str__(self) -> str:
        return self.name

    def describe(self) -> str:
        return f"J2735 {self.name} (TimeMark 0..{self.time_mark_max}, EmergencyDetails.{self.ssp_member})"


EDITIONS: dict[str, Edition] = {
    "2016": Edition("2016", 36001, 36001, 36000, None, "sspRights"),
    "2020": Edition("2020", 36111, 36111, 36009, (36010, 36110), "notUsed"),
}
SSP_MEMBERS = frozenset(e.ssp_member for e in EDITIONS.values())


def edition(name: "str | int | Edition | None" = None) -> Edition:
    """The edition called `name` (also an int such as 2016); None: $V2I_J2735_EDITION, else the default."""
    if isinstance(name, Edition):
        return name
    source = "edition"
    if name is None:
        name, source = os.environ.get(EDITION_ENV) or DEFAULT_EDITION, EDITION_ENV
    if isinstance(name, int) and not isinstance(name, bool):
        name = str(name)
    if isinstance(name, str) and name.strip() in EDITIONS:
        return EDITIONS[name.strip()]
    close = difflib.get_close_matches(str(name), list(EDITIONS), n=2, cutoff=0.5)
    hint = f"; did you mean {' or '.join(repr(c) for c in close)}?" if close else ""
    raise J2735Error(f"{source}: {name!r} is not a J2735 edition this codec knows "
                     f"({', '.join(EDITIONS)}){hint}")
