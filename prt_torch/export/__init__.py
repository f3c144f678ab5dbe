"""prt_torch.export."""
