"""One error type for everything a user can get wrong, so the CLI can print problem + fix and exit non-zero."""

from __future__ import annotations


class CompanionError(Exception):
    """A user-facing error: what is wrong, and what to do about it."""

    def __init__(self, problem: str, fix: str | None = None):
        super().__init__(problem)
        self.problem = problem
        self.fix = fix

    def __str__(self) -> str:
        return self.problem if not self.fix else f"{self.problem}\n  fix: {self.fix}"
