"""MkDocs hook: the Sphinx roles of snapflow's docstrings (``:class:`~snapflow.nn.SnapFlowPolicy```) as the code spans
a reader expects (``SnapFlowPolicy``), on the API reference that mkdocstrings renders from them: mkdocstrings-python
reads the docstrings' sections but leaves the roles as literal text."""

from __future__ import annotations

import re
from typing import Any

#: a role before the code span that Markdown made of its target; "~" keeps the target's last name only
ROLE = re.compile(r":(?:py:)?(?:class|func|meth|mod|data|attr|obj|exc|const):<code>(~?)([^<]+)</code>")


def _span(match: re.Match[str]) -> str:
    short, target = match.groups()
    return f"<code>{target.rsplit('.', 1)[-1] if short else target}</code>"


def on_page_content(html: str, **_: Any) -> str:
    return ROLE.sub(_span, html)
