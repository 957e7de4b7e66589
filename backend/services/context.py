"""What every service function receives: the database session, settings, storage and who is asking."""

from __future__ import annotations

from dataclasses import dataclass, field

from sqlalchemy.orm import Session

from ..core.settings import Settings
from ..models import User
from ..storage import Storage

SCOPES = ("read", "write", "admin")
# a token's scope grants the lower ones too: admin -> write -> read
SCOPE_IMPLIES = {"read": {"read"}, "write": {"read", "write"}, "admin": {"read", "write", "admin"},
                 # a tile token (POST /tokens/tile): reads map tiles and nothing else (docs/security.md)
                 "tiles": {"tiles"}}
TILE_SCOPE = "tiles"


@dataclass
class Principal:
    user: User
    via: str                          # "session" | "token"
    scopes: frozenset = field(default_factory=lambda: frozenset(SCOPES))
    session_id: str | None = None
    token_id: str | None = None
    csrf_token: str | None = None
    needs_touch: bool = False          # token whose last use was recorded more than a minute ago

    def has_scope(self, scope: str) -> bool:
        return scope in self.scopes

    @property
    def tiles_only(self) -> bool:
        """A tile token: it may only read map tiles (it can travel in a URL)."""
        return self.via == "token" and self.scopes == frozenset({"tiles"})


def expand_scopes(scopes) -> frozenset:
    out: set[str] = set()
    for s in scopes:
        out |= SCOPE_IMPLIES.get(s, set())
    return frozenset(out)


@dataclass
class Ctx:
    db: Session
    settings: Settings
    storage: Storage
    principal: Principal | None = None
    # messages to send to the broker once the transaction is committed: ("step", run_id, step)
    # or ("webhook", delivery_id)
    outbox: list[tuple] = field(default_factory=list)

    def commit(self) -> None:
        """Commit, then send what the transaction queued (never a message about uncommitted rows)."""
        self.db.commit()
        self.flush_outbox()

    def flush_outbox(self) -> None:
        from ..core.queue import send_part, send_step, send_webhook

        pending, self.outbox = self.outbox, []
        for msg in pending:
            if msg[0] == "step":
                send_step(self.settings, msg[1], msg[2])
            elif msg[0] == "part":
                send_part(self.settings, msg[1], msg[2], msg[3])
            elif msg[0] == "webhook":
                send_webhook(self.settings, msg[1])
            elif msg[0] == "design-change":
                from ..core.queue import send_design_change

                send_design_change(self.settings, msg[1])

    @property
    def user(self) -> User:
        assert self.principal is not None
        return self.principal.user
