"""Screenshots of the documentation site as a reader sees it, at desktop and at phone width, by headless Chromium
(Debian's ``chromium``): the home page, a tutorial, the Python API reference, the command-line reference, the
install page, a policy type's page, the cost page and the LIBERO results page (its headline table, and wide generated tables below it). The site is built with ``mkdocs build
--strict`` and served on the loopback for the shots.

    python scripts/docs_screenshots.py docs/screenshots             # every page
    python scripts/docs_screenshots.py docs/screenshots api cli     # only these
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import http.server
import shutil
import subprocess
import sys
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAGES = {
    "home": "",
    "tutorial": "tutorials/distil-lerobot/",
    "api": "reference/api/",
    "cli": "reference/cli/",
    "results": "results/libero/",
    "install": "install/",
    "type": "types/pi05/",
    "costs": "guides/distillation-cost/",
}
#: a desktop browser window and a phone's viewport (CSS pixels)
WIDTHS = {"desktop": (1280, 900), "phone": (390, 844)}


@contextlib.contextmanager
def served(site: Path) -> Iterator[str]:
    """The built site on a loopback port, for as long as the block runs."""
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(site))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}/"
    finally:
        server.shutdown()


def screenshot(browser: str, url: str, size: tuple[int, int], output: Path) -> None:
    width, height = size
    subprocess.run(
        [
            browser,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--hide-scrollbars",
            f"--window-size={width},{height}",
            f"--screenshot={output}",
            url,
        ],
        check=True,
        capture_output=True,
        timeout=120,
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("output", type=Path, help="folder for the PNGs (<page>-<width>.png)")
    parser.add_argument(
        "pages", nargs="*", metavar="PAGE", help=f"the pages to shoot, of {', '.join(PAGES)} (default: all)"
    )
    args = parser.parse_args()
    unknown = sorted(set(args.pages) - set(PAGES))
    if unknown:
        parser.error(f"no page named {', '.join(unknown)}; the pages are {', '.join(PAGES)}")
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        print("headless Chromium is needed: apt-get install chromium", file=sys.stderr)
        return 2
    args.output.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as scratch:
        site = Path(scratch) / "site"
        subprocess.run(
            [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)], cwd=ROOT, check=True
        )
        with served(site) as base:
            for page, path in PAGES.items():
                if args.pages and page not in args.pages:
                    continue
                for name, size in WIDTHS.items():
                    screenshot(browser, base + path, size, args.output / f"{page}-{name}.png")
                    print(f"{page} at {name} width: {args.output / f'{page}-{name}.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
