"""Physics-infused neural network soil-property estimator: model, offline trainer, evaluation and online node."""
