"""prt_torch.reduce."""
