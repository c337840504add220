"""Episodes of any policy: rollouts, held-out seeds, retention, and the act() adapters of
trees and BTs."""
