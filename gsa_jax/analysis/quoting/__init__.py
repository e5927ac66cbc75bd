"""Numbers in Markdown pages quoted from the committed tables, and flat PPO against published scores."""
