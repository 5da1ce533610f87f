"""Generated stress cases of every stage (issue 6): right answers or documented errors."""
