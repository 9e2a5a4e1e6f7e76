"""PPO training for torchpark through TorchRL's Collector, GAE and ClipPPOLoss."""
