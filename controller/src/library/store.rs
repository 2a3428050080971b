//! Saving and loading a [`ViewLibrary`](super::ViewLibrary): a versioned, checksummed file
//! written atomically. (Being written.)
