"""prt_torch.rig."""
