"""Jobs over folders. The engine (``engine``: lock, resume, progress, typed outcome; ``lock``,
``tasks``, ``progress``, ``state``) runs build and eval (``runner``, ``build``, ``evaluate``,
``object_store`` for URLs) and the LeRobot export (``export``); replay, verify, view and
migrate read or rewrite a finished folder."""
