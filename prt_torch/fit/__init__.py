"""prt_torch.fit."""
