"""Long-lived processes that answer from one loaded bundle: the HTTP service (`terra serve`,
terra.serve.app) and, later, the web viewer; both take the same terra.loaded.LoadedBundle."""
