"""Where a user's ``--policy``, ``--dataset`` or ``--vlm`` points, checked before a long load: an existing local
folder, a mistyped local path (named at once, never looked up on the hub), or a Hugging Face Hub repo whose first
file is fetched now, with every way that fails told apart in one line (:class:`HubError`).

Imports huggingface_hub only when a hub repo is checked; works with huggingface_hub 0.x (requests) and 1.x (httpx).
"""

from __future__ import annotations

import logging
import os
import re
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Literal

from snapflow.errors import InvalidInputError

# huggingface_hub's own rule for a repo id, narrowed to owner/name (every LeRobot policy and dataset has an owner)
_REPO_ID = re.compile(r"\w([\w.-]*\w)?/\w([\w.-]*\w)?")
# one request answers whether the hub is reachable; HF_HUB_ETAG_TIMEOUT (the user's, if set) bounds it
PROBE_TIMEOUT_S = 5.0


class HubError(InvalidInputError):
    """A Hugging Face Hub repo that cannot be used: the reason and the fix, in one line."""


def _is_repo_id(text: str) -> bool:
    """Whether ``text`` is a valid hub repo id of the form owner/name."""
    return (
        len(text) <= 96
        and "--" not in text
        and ".." not in text
        and not text.endswith(".git")
        and _REPO_ID.fullmatch(text) is not None
    )


def local_folder(text: str) -> Path | None:
    """The existing folder ``text`` names, or None for a hub repo id (owner/name).

    Anything else that looks like a local path (``./x``, ``/x``, ``~/x``, ``a/b/c``, a backslash, a bare name, or
    ``runs/x`` where ``runs/`` is a local folder) raises :class:`FileNotFoundError` naming it, so a mistyped folder
    is never looked up on the hub. Paths are taken literally, as LeRobot takes them (the shell expands ``~``).
    """
    path = Path(text)
    if path.is_dir():
        return path
    if path.exists():
        raise InvalidInputError(f"{text} is a file; give the folder that holds it")
    if _is_repo_id(text) and not Path(text.split("/")[0]).is_dir():
        return None
    existing = next(
        (parent for parent in path.parents if parent not in (Path("."), Path(path.anchor)) and parent.is_dir()), None
    )
    found = f" ({existing}/ exists)" if existing else ""
    raise FileNotFoundError(f"no folder {text}{found}; hub ids are owner/name")


def dataset_source(text: str, repo_id: str | None = None) -> tuple[Path | None, str]:
    """A user's ``--dataset`` as (root on disk, repo id: ``repo_id``, default ``local/<folder name>``), or (None, repo
    id) for a dataset LeRobot fetches and caches; a mistyped root is named here (:func:`local_folder`), before LeRobot
    loads."""
    root = local_folder(text)
    return root, (repo_id or f"local/{root.name}") if root else text


def check_source(text: str, filename: str, what: str, repo_type: Literal["model", "dataset"] = "model") -> None:
    """Check that ``text`` is ``what`` before it is loaded: a local folder holding ``filename``, or a hub repo whose
    ``filename`` is fetched now (:func:`fetch_hub_file`)."""
    folder = local_folder(text)
    if folder is None:
        fetch_hub_file(text, filename, what, repo_type)
    elif not (folder / filename).is_file():
        raise FileNotFoundError(f"{text} has no {filename}: not {what}")


def fetch_hub_file(repo_id: str, filename: str, what: str, repo_type: Literal["model", "dataset"] = "model") -> Path:
    """``filename`` of the hub repo ``repo_id`` fetched into the Hugging Face cache (where the library's own load
    then finds it), or a :class:`HubError` that tells an unreachable hub, a missing repo, a repo that needs
    authorisation and a repo that is not ``what`` (no ``filename``) apart.

    One request with a short timeout comes first: on a failed connection huggingface_hub < 1 retries five times
    (about 25 s) and logs each failure in full; with HF_HUB_OFFLINE set only the cache is read.
    """
    import huggingface_hub
    from huggingface_hub import constants
    from huggingface_hub.errors import EntryNotFoundError, HfHubHTTPError
    from huggingface_hub.utils import build_hf_headers, get_session, hf_raise_for_status

    try:
        with _hub_logs_silenced():
            if not constants.HF_HUB_OFFLINE:
                url = huggingface_hub.hf_hub_url(repo_id, filename, repo_type=repo_type)
                timeout = float(os.environ.get("HF_HUB_ETAG_TIMEOUT") or PROBE_TIMEOUT_S)
                try:
                    response = get_session().head(url, headers=build_hf_headers(), timeout=timeout)
                except _no_answer_errors() as error:
                    raise HubError(_unreachable(repo_id)) from error
                if response.status_code >= 400:
                    hf_raise_for_status(response)
            return Path(huggingface_hub.hf_hub_download(repo_id, filename, repo_type=repo_type))
    # EntryNotFoundError too: in huggingface_hub >= 1 the "not cached" LocalEntryNotFoundError is no HfHubHTTPError
    except (HfHubHTTPError, EntryNotFoundError) as error:
        raise _hub_error(error, repo_id, filename, what, repo_type) from error


def _unreachable(repo_id: str) -> str:
    from huggingface_hub import constants

    return (
        f"cannot reach the Hugging Face Hub ({constants.ENDPOINT}) to fetch {repo_id}; pass a local folder, "
        "or use a cached copy with HF_HUB_OFFLINE=1"
    )


def _hub_error(
    error: Exception, repo_id: str, filename: str, what: str, repo_type: Literal["model", "dataset"]
) -> HubError:
    """The one-line :class:`HubError` for what huggingface_hub raised (its classes differ between 0.x and 1.x,
    so the broad ones and the HTTP status decide)."""
    from huggingface_hub import constants
    from huggingface_hub.errors import (
        EntryNotFoundError,
        GatedRepoError,
        HfHubHTTPError,
        LocalEntryNotFoundError,
        RepositoryNotFoundError,
    )

    if isinstance(error, LocalEntryNotFoundError):  # not cached, and no usable answer from the hub
        if isinstance(error.__cause__, HfHubHTTPError):  # an HTTP error it folded into "not cached" (a 403, a 5xx)
            return _hub_error(error.__cause__, repo_id, filename, what, repo_type)
        if constants.HF_HUB_OFFLINE:
            return HubError(
                f"HF_HUB_OFFLINE is set and {repo_id} is not in the Hugging Face cache; unset it to download "
                "from the hub, or pass a local folder"
            )
        return HubError(_unreachable(repo_id))
    status = _status(error)
    # the hub answers 401 "RepoNotFound" for a missing repo too (so private ones cannot be probed): not a login issue
    if isinstance(error, GatedRepoError) or (status in (401, 403) and not isinstance(error, RepositoryNotFoundError)):
        page = f"{constants.ENDPOINT}/{'datasets/' if repo_type == 'dataset' else ''}{repo_id}"
        return HubError(
            f"{repo_id} needs authorisation: log in with `hf auth login` or set HF_TOKEN "
            f"(and accept its terms on {page})"
        )
    if isinstance(error, RepositoryNotFoundError):
        return HubError(
            f"no {repo_type} {repo_id} on the Hugging Face Hub (check the id; a private repo needs `hf auth login` "
            "or HF_TOKEN)"
        )
    if isinstance(error, EntryNotFoundError):
        return HubError(f"{repo_id} has no {filename}: not {what}")
    return HubError(
        f"the Hugging Face Hub answered HTTP {status} for {repo_id}; try again later, or pass a local folder"
    )


def _status(error: Exception) -> int | None:
    return getattr(getattr(error, "response", None), "status_code", None)


def _no_answer_errors() -> tuple[type[BaseException], ...]:
    """What the hub's HTTP client raises when no answer comes: requests' errors are OSErrors (huggingface_hub < 1),
    httpx's are not (huggingface_hub >= 1)."""
    try:
        import httpx
    except ImportError:
        return (OSError,)
    return (OSError, httpx.TransportError)


@contextmanager
def _hub_logs_silenced() -> Iterator[None]:
    """huggingface_hub < 1 logs a warning with the whole connection error (a MaxRetryError) on every retry."""
    logger = logging.getLogger("huggingface_hub")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        logger.setLevel(level)


__all__ = ["HubError", "PROBE_TIMEOUT_S", "local_folder", "dataset_source", "check_source", "fetch_hub_file"]
