"""The engine's exception hierarchy.

Every message names the thing, the bad value and the fix; causes are chained with
``raise ... from exc`` so the original traceback is kept.
"""

from __future__ import annotations


class MocapflowError(Exception):
    """Base of every error mocapflow raises on purpose."""


class CatalogError(MocapflowError):
    """catalog.yaml (or a --set override) is invalid."""


class SchemaError(MocapflowError):
    """An artifact does not match its declared schema."""


class InputError(MocapflowError):
    """A raw input (recording, calibration, BVH, layout file) is unusable."""


class StorageError(MocapflowError):
    """The artifact store is missing, incomplete or unreadable."""


class LockError(StorageError):
    """Another live run holds the lock of a partition."""


class PlanError(MocapflowError):
    """The requested run cannot be planned (e.g. --only with missing inputs)."""


class IntegrityError(StorageError):
    """A stored artifact's bytes differ from what was committed (a chunk deleted, truncated or altered)."""


class InputWarning(UserWarning):
    """Input that is usable but likely not what was meant (a subject leaving a camera's view). Raised with
    ``warnings.warn`` anywhere a partition is computed; the engine carries it to the run's console and log."""
