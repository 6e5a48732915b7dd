"""MkDocs hook: the site's search weighs a page by what a reader who types a task wants first. The how-to pages
(tutorials, a policy type's page) before the results pages, which name the same policies and commands a hundred
times over as evidence ("distill pi0.5" put a latency result first). Material for MkDocs reads a page's
``search.boost``; it is set here, by folder, instead of in each page's front matter (the pages read as they are on
GitHub, where front matter shows as a table)."""

from __future__ import annotations

from typing import Any

#: a page's folder under docs/ and its search weight (Material's default is 1)
BOOSTS = {"tutorials/": 4.0, "types/": 2.0, "guides/": 1.5, "results/": 0.5}


def on_page_markdown(markdown: str, page: Any, **_: Any) -> str:
    for folder, boost in BOOSTS.items():
        if page.file.src_uri.startswith(folder):
            page.meta.setdefault("search", {}).setdefault("boost", boost)
    return markdown
