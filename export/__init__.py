"""``python -m export RUN``: thin entry point of the export job (see :mod:`prt_torch.commands.export`)."""
