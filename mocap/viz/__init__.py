"""Pictures: shaded mesh renders, the rasterizer behind them, and matplotlib figures."""
