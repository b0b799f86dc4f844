"""Training TP-Net in PyTorch (optional ``train`` extra): the torch model, the recipe, the loop."""
