"""The browser trainer: a FastAPI app serving the trainer page, a WebSocket state stream and the
OpenIGTLink listener in one process (``thrsim serve``). Modes (navigation at ``/``; reaming
later) plug in through :mod:`thrsim.app.modes`. The FastAPI side is imported only by
:func:`create_app`'s module, so the trainer logic and recording load without it."""
