"""Where an asset's loader may read: the asset's own folder and the roots the user allows.

Downloaded assets are hostile input: a glTF image URI ``../../etc/passwd``, a symlink beside the
asset pointing at a private file, or a USD sublayer ``/home/me/.ssh/id_rsa`` would otherwise put
another file's bytes into the stage cache and the outputs. Every loader asks `Confinement.check`
before it opens any file other than the asset itself.
"""

from __future__ import annotations

import os
import stat
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from sssbake.pipeline.core.errors import AssetError


@dataclass(frozen=True)
class Confinement:
    """The folders one asset's loader may read from.

    Attributes
    ----------
    asset : str
        The asset file, as the batch names it (errors name it).
    roots : tuple of Path
        Real (symlink-free, absolute) folders; a file is readable when its real path lies in one.
    """

    asset: str
    roots: tuple[Path, ...]

    @classmethod
    def for_asset(cls, asset: str | os.PathLike, allow_roots: Iterable[str | os.PathLike] = ()) -> "Confinement":
        """The asset's folder (as named, and where a symlinked asset really lives) and `allow_roots`."""
        asset = os.fspath(asset)
        here = Path(os.path.abspath(asset)).parent
        roots = [here.resolve(), Path(os.path.realpath(asset)).parent]
        roots += [Path(r).resolve() for r in allow_roots]
        return cls(asset, tuple(dict.fromkeys(roots)))

    def allows(self, target: str | os.PathLike) -> bool:
        """Whether `target`'s real path lies under one of the roots."""
        real = Path(os.path.realpath(target))
        return any(real == r or r in real.parents for r in self.roots)

    def check(self, target: str | os.PathLike, what: str) -> Path:
        """The real path of `target`, a regular file under one of the roots.

        Parameters
        ----------
        target : str or os.PathLike
            The file a reference resolves to (relative paths are taken from the working folder:
            resolve references against the asset's folder first).
        what : str
            The reference as the user would find it in the file, e.g. ``"image 0 URI '../x.png'"``.

        Raises
        ------
        AssetError
            When the real path lies outside every root (naming the fix, ``--allow-root``), or is
            not a regular file (a folder, a FIFO or a device would hang or mislead the reader).
            A missing file is left to the reader, which names it in its own words.
        """
        real = Path(os.path.realpath(target))
        if not self.allows(real):
            raise AssetError(self.asset, f"{what} resolves to {real}, outside the asset's folder; refused "
                                         f"(pass --allow-root {real.parent} to read it)")
        try:
            mode = real.stat().st_mode
        except OSError:
            return real
        if not stat.S_ISREG(mode):
            raise AssetError(self.asset, f"{what} resolves to {real}, which is not a regular file")
        return real
