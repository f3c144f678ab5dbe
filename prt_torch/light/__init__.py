"""prt_torch.light."""
