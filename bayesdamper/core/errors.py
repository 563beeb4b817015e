"""The toolkit's own error types.

Every error a user can cause (bad files, bad settings, impossible parameters) is raised as a
:class:`BayesDamperError` whose message is one line naming the file or setting and the problem.
The command line prints that line and exits non-zero; it never shows a traceback for these.
"""

from __future__ import annotations


class BayesDamperError(Exception):
    """Base class of every user-facing error; ``str(err)`` is a single line."""


class DataError(BayesDamperError):
    """A data set, a file in it or a value read from it is missing or malformed."""


class SettingsError(BayesDamperError):
    """A command-line setting or parameter value is impossible."""
