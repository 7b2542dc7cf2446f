//! burn networks and their training: Q-networks and the DQN family for the driving tasks,
//! and the PSPNet-style segmenter.
