"""prt_torch.player."""
