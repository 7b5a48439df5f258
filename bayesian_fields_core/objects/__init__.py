"""Objects: primitives from masks, their task probabilities, the overlap graph, AIB clustering,
pruning and top-k selection, and floater removal (`obb` computes oriented boxes)."""
