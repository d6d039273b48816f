"""What makes the stages' answer dependable on hard rigs: the consensus over differently seeded
runs, focal hops between minima, moving cameras the matches contradict."""
