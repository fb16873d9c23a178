"""What a reconstruction tells its user: the JSON report, the HTML report, previews."""
