"""The ES module graph of `sssbake view`'s page, fetched over HTTP as a browser would: the page's
import map, its module scripts, and every module they import, transitively (used by the vendored
three.js test and the installed wheel's test)."""

import json
import re
import urllib.error
import urllib.parse
import urllib.request

# Static imports and re-exports: the specifier after `from`, or right after `import` for a module
# imported for its effects. Anchored at a line's start so that an example in a comment
# (`//   import { X } from './a.js'`) is not taken for one; `[^;'"`]*?` spans a multi-line `{ ... }`.
_STATIC = re.compile(r"""^[ \t]*(?:import|export)\b[^;'"`]*?\bfrom[ \t]*(['"])(?P<a>[^'"]+)\1"""
                     r"""|^[ \t]*import[ \t]*(['"])(?P<b>[^'"]+)\3""", re.M)
# import('literal'): a module the browser loads later, still one the page needs served
_DYNAMIC = re.compile(r"""\bimport\(\s*(['"])(?P<c>[^'"]+)\1\s*\)""")
_IMPORT_MAP = re.compile(r"""<script\s+type=["']importmap["']\s*>(.*?)</script>""", re.S | re.I)
_MODULE_SCRIPT = re.compile(r"""<script\s+type=["']module["'][^>]*\bsrc=["']([^"']+)["']""", re.I)


def specifiers(source: str) -> list[str]:
    """The module specifiers a JavaScript module imports, statically or with a literal ``import()``."""
    found = [m.group("a") or m.group("b") for m in _STATIC.finditer(source)]
    return found + [m.group("c") for m in _DYNAMIC.finditer(source)]


def resolve(specifier: str, base: str, imports: dict[str, str]) -> str:
    """The URL a browser loads for `specifier` imported by the module at URL `base`.

    Parameters
    ----------
    specifier : str
    base : str
        URL of the importing module (or page).
    imports : dict
        The import map's ``imports``: exact names and prefixes ending in ``/``.

    Raises
    ------
    ValueError
        A bare specifier the import map does not name: the browser refuses it.
    """
    if specifier in imports:
        return urllib.parse.urljoin(base, imports[specifier])
    prefix = max((k for k in imports if k.endswith("/") and specifier.startswith(k)), key=len, default=None)
    if prefix is not None:
        return urllib.parse.urljoin(base, imports[prefix] + specifier[len(prefix):])
    if specifier.startswith(("/", "./", "../")) or "://" in specifier:
        return urllib.parse.urljoin(base, specifier)
    raise ValueError(f"bare specifier {specifier!r} (imported by {base}) is not in the page's import map")


def fetch(url: str) -> bytes:
    """The body of a 200 answer; AssertionError naming the URL otherwise."""
    try:
        with urllib.request.urlopen(url, timeout=30) as response:
            assert response.status == 200, f"{url}: HTTP {response.status}"
            return response.read()
    except urllib.error.HTTPError as e:
        raise AssertionError(f"{url}: HTTP {e.code}") from None


def page_modules(page_url: str) -> dict[str, bytes]:
    """Every module the page at `page_url` loads, URL -> body, the page itself first; each fetched
    and asserted 200 and non-empty."""
    page = fetch(page_url).decode()
    maps = _IMPORT_MAP.findall(page)
    imports = json.loads(maps[0])["imports"] if maps else {}
    todo = [urllib.parse.urljoin(page_url, src) for src in _MODULE_SCRIPT.findall(page)]
    assert todo, f"{page_url}: no <script type=module src=...>"
    bodies = {page_url: page.encode()}
    while todo:
        url = todo.pop()
        if url in bodies:
            continue
        body = fetch(url)
        assert body, f"{url}: empty"
        bodies[url] = body
        todo += [resolve(s, url, imports) for s in specifiers(body.decode())]
    return bodies
