"""The command-line tools built on the library: ``bipedtele demo``, ``report``, ``router``, ...

Each module adds one or more sub-commands (registered in the ``bipedtele.commands``
entry-point group of ``pyproject.toml``). The library (``bipedtele`` without this package)
never imports them; the tools may use the optional extras (matplotlib for figures,
tqdm for progress bars).
"""
