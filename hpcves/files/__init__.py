"""Files that are always whole: replacement by rename, byte-range locks, fault points for tests."""
