"""The documentation site's search as a reader's browser runs it: headless Chromium loads a page of the built site
that hands Material for MkDocs' own search worker the site's own index and one query, and posts the ranked pages back
to the test's loopback server (the page's load waits for that post, so Chromium's ``--dump-dom`` returns after it)."""

from __future__ import annotations

import functools
import http.server
import json
import subprocess
import threading
from pathlib import Path

HARNESS = """<!doctype html><html><body><script>
const worker = new Worker("WORKER");
fetch("search/search_index.json").then(reply => reply.json()).then(index => {
  worker.onmessage = message => {  // Material's messages: 0 set up, 1 ready, 2 query, 3 result
    if (message.data.type === 1) worker.postMessage({type: 2, data: QUERY});
    if (message.data.type === 3) fetch("result", {method: "POST", body: JSON.stringify(
      message.data.data.items.map(group => group[0].location))});
  };
  worker.postMessage({type: 0, data: {...index, options: {suggest: false}}});
});
</script><script src="wait-for-result.js"></script></body></html>"""


class _SearchHandler(http.server.SimpleHTTPRequestHandler):
    """Serves the site; takes the harness's posted result and holds the page's last script until it arrives."""

    def __init__(self, *args, arrived: threading.Event, result: list[str], **kwargs) -> None:
        self.arrived, self.result = arrived, result
        super().__init__(*args, **kwargs)

    def do_POST(self) -> None:  # noqa: N802 (http.server's naming)
        self.result.extend(json.loads(self.rfile.read(int(self.headers["Content-Length"]))))
        self.arrived.set()
        self.send_response(204)
        self.end_headers()

    def do_GET(self) -> None:  # noqa: N802
        if self.path.endswith("wait-for-result.js"):
            self.arrived.wait(timeout=60)
            self.send_response(200)
            self.send_header("Content-Type", "text/javascript")
            self.end_headers()
            return
        super().do_GET()

    def log_message(self, *args) -> None:
        pass


def ranked_pages(site: Path, query: str, browser: str) -> list[str]:
    """The locations (``page/#section``) Material's search returns for ``query`` on the built ``site``, best first,
    one a page."""
    (worker,) = (site / "assets" / "javascripts" / "workers").glob("search.*.min.js")
    harness = HARNESS.replace("WORKER", worker.relative_to(site).as_posix()).replace("QUERY", json.dumps(query))
    (site / "search-harness.html").write_text(harness)
    arrived, result = threading.Event(), []
    handler = functools.partial(_SearchHandler, directory=str(site), arrived=arrived, result=result)
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        url = f"http://127.0.0.1:{server.server_address[1]}/search-harness.html"
        subprocess.run(
            [browser, "--headless", "--no-sandbox", "--disable-gpu", "--dump-dom", url],
            capture_output=True,
            timeout=120,
            check=True,
        )
    finally:
        server.shutdown()
    assert arrived.is_set(), "the search worker posted no result"
    return result
