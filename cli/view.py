"""`tetweave view`: look at a `.tw` file (or a mesh, encoded first) in the browser viewer (web/viewer).

The page decodes the file with the WebAssembly build of the C decoder core (web/tetweave_decoder.wasm) in a Web
Worker and draws it with three.js (vendored under web/vendor): nothing is fetched from outside this machine. This
command only serves those files and the one `.tw` file on 127.0.0.1, until Ctrl-C.
"""

from __future__ import annotations

import functools
import http.server
import tempfile
import threading
import urllib.parse
import webbrowser
from pathlib import Path

import click

# The web files: web/ of the checkout, installed as the package tetweave_codec.web beside tetweave_codec.cli
# (pyproject's package-dir), so one level up from this file in both layouts.
WEB = Path(__file__).resolve().parent.parent / "web"
VIEWER_PAGE = "viewer/index.html"
FILE_ROUTE = "/file/"  # the one .tw file this server shows, under its own name
TYPES = {
    ".mjs": "text/javascript",
    ".js": "text/javascript",
    ".wasm": "application/wasm",
    ".tw": "application/octet-stream",
}


class ViewerHandler(http.server.SimpleHTTPRequestHandler):
    """Serves web/ read-only (SimpleHTTPRequestHandler keeps paths inside its directory) and the .tw file at
    FILE_ROUTE + its name. No directory listings, no caching (a rebuilt module or a re-encoded file shows at once)."""

    extensions_map = {**http.server.SimpleHTTPRequestHandler.extensions_map, **TYPES}

    def __init__(self, *args, tw_file: Path, quiet: bool, **kwargs):
        self.tw_file = tw_file
        self.quiet = quiet
        super().__init__(*args, **kwargs)

    def do_GET(self) -> None:
        path = urllib.parse.unquote(urllib.parse.urlsplit(self.path).path)
        if path == FILE_ROUTE + self.tw_file.name:
            data = self.tw_file.read_bytes()  # read per request: `tetweave encode` may rewrite it meanwhile
            self.send_response(200)
            self.send_header("Content-Type", TYPES[".tw"])
            self.send_header("Content-Length", str(len(data)))
            self.end_headers()
            self.wfile.write(data)
            return
        if path == "/":
            self.send_response(302)
            self.send_header("Location", viewer_path(self.tw_file))
            self.end_headers()
            return
        super().do_GET()

    def list_directory(self, path):
        self.send_error(404, "No listing")
        return None

    def end_headers(self) -> None:
        self.send_header("Cache-Control", "no-store")
        super().end_headers()

    def log_message(self, format: str, *args) -> None:  # noqa: A002 (the base class's name)
        if not self.quiet:
            super().log_message(format, *args)


def viewer_path(tw_file: Path) -> str:
    """The page's path with ?file= pointing at the served file."""
    return f"/{VIEWER_PAGE}?file={urllib.parse.quote(FILE_ROUTE + urllib.parse.quote(tw_file.name))}"


def make_server(tw_file: Path, port: int = 0, quiet: bool = True) -> http.server.ThreadingHTTPServer:
    """A server on 127.0.0.1:`port` (0: a free one) for the viewer and `tw_file`; not yet serving."""
    missing = [name for name in (VIEWER_PAGE, "tetweave_decoder.wasm") if not (WEB / name).is_file()]
    if missing:
        raise click.ClickException(f"the viewer's files are missing from {WEB}: {', '.join(missing)}")
    handler = functools.partial(ViewerHandler, directory=str(WEB), tw_file=tw_file.resolve(), quiet=quiet)
    try:
        return http.server.ThreadingHTTPServer(("127.0.0.1", port), handler)
    except OSError as exc:
        raise click.BadParameter(f"cannot listen on 127.0.0.1:{port}: {exc.strerror}", param_hint="--port") from None


def _encode_first(ctx: click.Context, mesh: Path, output: Path | None, workdir: Path) -> Path:
    """`tetweave encode MESH -o OUTPUT` with every other option at its default; returns the .tw path."""
    from tetweave_codec.cli.encode import encode

    target = output or workdir / (mesh.stem + ".tw")
    click.echo(f"tetweave view: encoding {mesh} with the defaults of tetweave encode ...", err=True)
    ctx.invoke(encode, inputs=(str(mesh),), output=target)
    return target


@click.command(context_settings={"show_default": True})
@click.argument("file", metavar="FILE.tw|MESH", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--port", type=click.IntRange(0, 65535), default=0, help="Port on 127.0.0.1 (0: a free one).")
@click.option("--no-browser", is_flag=True, help="Only print the URL; do not open a browser.")
@click.option(
    "-o",
    "--output",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="MESH only: where to keep its encoded .tw file.  [default: a temporary file, deleted on exit]",
)
@click.option("--verbose", is_flag=True, help="Log every request on stderr.")
@click.pass_context
def view(ctx: click.Context, file: Path, port: int, no_browser: bool, output: Path | None, verbose: bool) -> None:
    """Show FILE.tw, or MESH (OBJ, PLY, STL, OFF, GLB) encoded first with `tetweave encode`'s defaults, in the
    browser viewer: orbit controls, bytes, faces, decode time and the decode level (control, smoothed, full).
    Other .tw files can be opened or dropped on the page.

    The page and the file are served on 127.0.0.1 only, until Ctrl-C. The browser decodes the file itself, with
    the WebAssembly build of the decoder: the same mesh as `tetweave decode`.
    """
    from tetweave_codec.meshio import MESH_FORMATS

    with tempfile.TemporaryDirectory(prefix="tetweave-view-") as workdir:
        suffix = file.suffix.lower()
        if suffix == ".tw":
            if output is not None:
                raise click.BadParameter("only for a MESH: FILE is already a .tw file", param_hint="-o/--output")
            tw_file = file
        elif suffix in MESH_FORMATS:
            tw_file = _encode_first(ctx, file, output, Path(workdir))
        else:
            names = ", ".join(e[1:] for e in MESH_FORMATS)
            raise click.BadParameter(f"{file}: not a .tw file nor a mesh ({names})", param_hint="FILE.tw|MESH")
        server = make_server(tw_file, port, quiet=not verbose)
        url = f"http://127.0.0.1:{server.server_address[1]}{viewer_path(tw_file)}"
        click.echo(f"tetweave view: serving {tw_file} at {url}")
        click.echo("press Ctrl-C to stop", err=True)
        if not no_browser:
            _open_browser(url)
        try:
            server.serve_forever()
        except KeyboardInterrupt:
            click.echo("tetweave view: stopped", err=True)
        finally:
            server.server_close()


def _open_browser(url: str) -> None:
    """Open `url` in the user's browser from a thread (a slow browser start does not delay serving); say so when
    there is none (a server without a display)."""
    try:
        browser = webbrowser.get()
    except webbrowser.Error:
        click.echo("tetweave view: no browser found here; open the URL above in one", err=True)
        return
    threading.Thread(target=browser.open, args=(url,), daemon=True).start()
