"""A trial's own code: the local files a ``model`` or ``env_module`` imports (found by parsing them with ``ast``),
hashed into the trial key, shipped with the trial and put on ``sys.path`` on whichever node trains it.

Standard library only. Local means found in a root folder: a ``FILE.py`` factory's own folder, or the experiment's
for a ``package.module``. The standard library and installed packages are not local: they are recorded by version.
"""

from __future__ import annotations

import ast
import atexit
import functools
import hashlib
import importlib
import importlib.metadata
import importlib.util
import json
import shutil
import sys
import tempfile
import types
from pathlib import Path

Bundle = tuple[tuple[str, str], ...]
"""A module and its local imports as ``(path relative to the root, text)`` pairs: the module first, then the
files it imports (transitively) sorted by path."""


class SourceError(ValueError):
    """Code that cannot be found, shipped or run; the message is one line (the caller names the key)."""


def is_module_spec(value: object) -> bool:
    """``package.module`` or ``package.module:function``: what ``env_module`` may be."""
    if not isinstance(value, str):
        return False
    module, colon, function = value.partition(":")
    return all(p.isidentifier() for p in module.split(".")) and (not colon or function.isidentifier())


def bundle_hash(bundle: Bundle) -> str:
    """12 hex digits of SHA-1: of the one file's text where there is one (the hash keys had before helpers were
    shipped, so such keys never change), of every path and text together where a file imports others. Empty files
    (a package's bare ``__init__.py``) ship but do not count: they run nothing, and a module of a package keeps
    the hash of its own text."""
    counted = bundle[:1] + tuple(pair for pair in bundle[1:] if pair[1])
    if len(counted) == 1:
        return hashlib.sha1(counted[0][1].encode()).hexdigest()[:12]
    return hashlib.sha1(json.dumps([list(pair) for pair in counted]).encode()).hexdigest()[:12]


def _read(path: Path) -> str:
    with open(path, encoding="utf-8", newline="") as file:  # the bytes as they are: the hash is the file's
        return file.read()


def local_path(root: Path, name: str) -> Path | None:
    """The file of module ``name`` under ``root`` (a package's ``__init__.py``, else ``name.py``); None where the
    module is not local (the standard library's, or no such file there)."""
    if name.split(".")[0] in sys.stdlib_module_names:
        return None
    base = root.joinpath(*name.split("."))
    for path in (base / "__init__.py", base.parent / f"{base.name}.py"):
        if path.is_file():
            return path
    return None


def _with_parents(name: str) -> set[str]:
    parts = name.split(".")
    return {".".join(parts[:i]) for i in range(1, len(parts) + 1)}


def imported_names(text: str, package: str) -> set[str]:
    """Every module an import in ``text`` (top level or not) may load, with its parent packages; a from-import's
    names count as possible submodules. ``package``: the importing module's package ("" at the top), against which
    relative imports resolve. A file that does not parse imports nothing here (importing it will say why)."""
    try:
        tree = ast.parse(text)
    except (SyntaxError, ValueError):
        return set()
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                names |= _with_parents(alias.name)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = package.split(".") if package else []
                if node.level - 1 >= len(parts):
                    continue  # outside any package, or beyond the top one: Python refuses it when it runs
                base = ".".join(parts[: len(parts) - node.level + 1] + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            if not base:
                continue
            names |= _with_parents(base)
            names |= {f"{base}.{alias.name}" for alias in node.names if alias.name != "*"}
    return names


def _module_name(relative: str) -> str:
    parts = relative.removesuffix(".py").split("/")
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def collect(root: Path, entry: Path, entry_text: str) -> tuple[Bundle, str]:
    """``entry`` (a file under ``root``, its text already read) and every local file it imports, transitively, and
    their ``bundle_hash``."""
    root = root.resolve()
    first = entry.resolve().relative_to(root).as_posix()
    files = {first: entry_text}
    queue = [first]
    while queue:
        relative = queue.pop()
        name = _module_name(relative)
        package = name if relative.endswith("__init__.py") else name.rpartition(".")[0]
        parents = _with_parents(name) - {name} if "." in name else set()  # a package's __init__ runs first
        for imported in sorted(imported_names(files[relative], package) | parents):
            path = local_path(root, imported)
            if path is None:
                continue
            other = path.resolve().relative_to(root).as_posix()
            if other not in files:
                files[other] = _read(path)
                queue.append(other)
    bundle = ((first, entry_text), *sorted((p, t) for p, t in files.items() if p != first))
    return bundle, bundle_hash(bundle)


def resolve_model(target: str, base_dir: Path) -> tuple[Bundle, str]:
    """``model``'s target (``FILE.py`` relative to ``base_dir``, or ``package.module``) as (what ships, its hash).
    A file, or a module under ``base_dir``, ships with its local imports; another module on the path is only
    hashed (each node imports its own). ``SourceError`` where there is no such file or module."""
    if target.endswith(".py"):
        path = (base_dir / target).resolve()
        if not path.is_file():
            raise SourceError(f"no such file {path}")
        # read_text as keys were always made from it (newlines translated): an unchanged file keeps its hash
        return collect(path.parent, path, path.read_text(encoding="utf-8"))
    path = local_path(base_dir, target)
    if path is not None:
        return collect(base_dir, path, _read(path))
    try:
        found = importlib.util.find_spec(target)
    except (ImportError, ValueError) as error:
        raise SourceError(f"cannot import {target} ({error})") from None
    if found is None or not found.origin or not Path(found.origin).is_file():
        raise SourceError(f"no module {target} in {base_dir} or on the Python path")
    return (), hashlib.sha1(Path(found.origin).read_bytes()).hexdigest()[:12]


def resolve_env_module(spec: str, base_dir: Path) -> tuple[Bundle, str]:
    """``env_module``'s (what ships, its hash): a module under ``base_dir`` with its local imports; ``((), "")`` for
    any other (installed, or on the path: each node imports its own, and the key holds only its name)."""
    module = spec.partition(":")[0]
    path = local_path(base_dir, module)
    if path is None:
        return (), ""
    return collect(base_dir, path, _read(path))


# --- on the node (or wherever a trial builds its network and env) ---
_FOLDERS: dict[str, Path] = {}


def install(bundle: Bundle, digest: str) -> Path:
    """Write ``bundle`` into a folder of this process's own, first on ``sys.path``, so its modules import from
    there; modules of the same names imported from elsewhere (another variant's helpers) are dropped first.
    ``SourceError`` where the files are not the ones ``digest`` was made from."""
    if bundle_hash(bundle) != digest:
        raise SourceError(f"its shipped files do not match the trial's hash {digest}")
    folder = _FOLDERS.get(digest)
    if folder is None:
        folder = Path(tempfile.mkdtemp(prefix=f"ablate-code-{digest}-"))
        atexit.register(shutil.rmtree, folder, True)
        for relative, text in bundle:
            path = folder / relative
            path.parent.mkdir(parents=True, exist_ok=True)
            with open(path, "w", encoding="utf-8", newline="") as file:
                file.write(text)
        _FOLDERS[digest] = folder
    if str(folder) in sys.path:
        sys.path.remove(str(folder))
    sys.path.insert(0, str(folder))
    for relative, _ in bundle:
        cached = sys.modules.get(_module_name(relative))
        origin = getattr(cached, "__file__", None) or ""
        if cached is not None and not origin.startswith(str(folder)):
            del sys.modules[_module_name(relative)]
    importlib.invalidate_caches()
    return folder


def load_function(spec: str, bundle: Bundle, digest: str):
    """The function ``spec`` (``FILE.py:FUNCTION`` or ``package.module:FUNCTION``) names, its shipped files put on
    the path first (checked against ``digest``), so no file is needed on this node; a ``FILE.py`` runs as a module
    of its own (one per ``digest``), a ``package.module`` is imported. ``SourceError`` saying what failed."""
    target, function = spec.rsplit(":", 1)
    if bundle:
        install(bundle, digest)
    if target.endswith(".py"):
        name = f"ablate_model_{digest}"
        module = sys.modules.get(name)
        if module is None:
            module = types.ModuleType(name)
            module.__file__ = target
            try:
                exec(compile(bundle[0][1], target, "exec"), module.__dict__)
            except Exception as error:  # a user's file: any error is theirs to read, in one line
                raise SourceError(f"{target} raised {type(error).__name__}: {error}") from None
            sys.modules[name] = module
    else:
        try:
            module = importlib.import_module(target)
        except Exception as error:
            raise SourceError(f"cannot import {target} ({type(error).__name__}: {error})") from None
    found = getattr(module, function, None)
    if not callable(found):
        raise SourceError(f"{target} has no function {function}")
    return found


_CALLED: set[tuple[str, str]] = set()


def run_env_module(spec: str, bundle: Bundle, digest: str) -> None:
    """Import ``env_module`` (from its shipped files where it has some) and call its function where ``spec`` names
    one (once per process). ``SourceError`` saying what failed, in one line."""
    module_name, _, function = spec.partition(":")
    if bundle:
        install(bundle, digest)
    try:
        module = importlib.import_module(module_name)
    except Exception as error:  # a user's module: any error is theirs to read, in one line
        raise SourceError(f"cannot import it ({type(error).__name__}: {error})") from None
    if not function or (spec, digest) in _CALLED:
        return
    register = getattr(module, function, None)
    if not callable(register):
        raise SourceError(f"{module_name} has no function {function}")
    try:
        register()
    except Exception as error:
        raise SourceError(f"{function}() raised {type(error).__name__}: {error}") from None
    _CALLED.add((spec, digest))


_distributions = functools.cache(importlib.metadata.packages_distributions)


def package_version(module: str) -> str:
    """``name==version`` of the installed distribution that provides ``module``; "" for none (a local module)."""
    names = _distributions().get(module.split(".")[0], [])
    if not names:
        return ""
    try:
        return f"{names[0]}=={importlib.metadata.version(names[0])}"
    except importlib.metadata.PackageNotFoundError:
        return ""
