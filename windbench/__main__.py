from windbench.cli import main

main()
