"""One module per ``prt`` sub-command (see :mod:`prt_torch.cli`)."""
