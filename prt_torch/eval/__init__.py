"""prt_torch.eval."""
